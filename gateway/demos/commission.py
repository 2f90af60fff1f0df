"""`compgw demo --commission`: `compgw commission` live on a random machine, in one process.

A smooth random machine (`compgw sim --random-machine 7`, its travel cut to 120 mm so the
whole run takes seconds), the sim at time_scale 0 and the gateway on free loopback ports,
then the commissioning exactly as the command runs it (the gateway reloaded through its own
reload path), printed as it goes. `compgw demo` shows a saved run of it
(``config/commission-demo.txt``, written by ``--commission --save``).
"""

from __future__ import annotations

import asyncio
import tempfile
from pathlib import Path
from typing import Any

import yaml

from ..app import GatewayApp, load
from ..calibration.commissioning.commission import Commission
from ..calibration.commissioning.report import summary_lines
from ..calibration.commissioning.steps import Settings
from ..calibration.measuring.machine import Endpoint
from ..calibration.measuring.session import Instruments

SEED, TRAVEL_MM = 7, (0.0, 120.0)
SAVED = Path(__file__).resolve().parents[2] / "config" / "commission-demo.txt"


def _machine(work: Path) -> dict[str, Any]:
    from sim.machine_files import write_machine
    from sim.random_machine import random_machine

    write_machine(random_machine(SEED, "smooth"), work)
    sim = yaml.safe_load((work / "sim.yaml").read_text())
    for axis in sim["sim"]["axes"].values():
        axis["travel_mm"] = list(TRAVEL_MM)
    (work / "sim.yaml").write_text(yaml.safe_dump(sim, sort_keys=False))
    return sim


async def live(say: Any = print) -> dict[str, Any]:
    """Commission the demo machine; every line said as it comes; the summary returned."""
    from sim.config import load_config as load_sim
    from sim.server import SimServer

    with tempfile.TemporaryDirectory(prefix="compgw-commission-") as tmp:
        work = Path(tmp)
        _machine(work)
        async with SimServer(load_sim(work / "sim.yaml"), tcp_port=0, time_scale=0) as sim:
            data = yaml.safe_load((work / "gateway.yaml").read_text())
            data.pop("thermal_sources", None)  # no sensor given: heat from motion (the demo's)
            for axis in data["axes"].values():
                axis["travel_mm"] = list(TRAVEL_MM)
                axis["compensation"].pop("thermal", None)
            data["upstream"]["tcp"]["port"] = 0
            data["buses"]["line1"]["tcp"]["port"] = sim.tcp_port
            data["status"]["remote_control"] = True
            path = work / "gw.yaml"
            path.write_text(yaml.safe_dump(data, sort_keys=False))
            config, chain = load(path)
            async with GatewayApp(config, chain, source=str(path)) as app:

                async def reload() -> None:
                    refused = await app.reload_file()
                    if refused is not None:
                        raise RuntimeError(f"the gateway refused the config: {refused}")

                machine = yaml.safe_load((work / "machine.json").read_text())
                leads = {a: float(v["lead_mm"]) for a, v in machine["axes"].items()}
                sim_ep = f"127.0.0.1:{sim.tcp_port}"
                settings = Settings(
                    config_path=path, out_dir=work / "commission",
                    gateway=Endpoint.parse(f"127.0.0.1:{app.tcp_port}"),
                    instruments=Instruments(laser=Endpoint.parse(f"{sim_ep}:20"),
                                            xy=Endpoint.parse(f"{sim_ep}:21")),
                    axes=("X", "Y"), planar=("X", "Y"), lead_mm=leads,
                    # the demo's seconds: no zone warm-up for heat from motion at the end
                    # (it would triple them); the drift references' fit stands
                    heat_warmup=False,
                )  # fmt: skip
                job = Commission(settings, reload, say)
                say(f"compgw commission on random machine {SEED} (smooth), its travel cut "
                    f"to {TRAVEL_MM[1]:g} mm so the demo takes seconds (`compgw sim "
                    f"--random-machine {SEED}` writes it whole), leads {leads}")  # fmt: skip
                job.command.print_plan()
                summary = await job.run()
    for line in summary_lines(summary):
        say(line)
    return summary


def main(save: str | None = None) -> int:
    lines: list[str] = []

    def say(line: str) -> None:
        lines.append(line)
        print(line, flush=True)

    asyncio.run(live(say))
    if save:
        Path(save).write_text("\n".join(lines) + "\n")
    return 0


def saved() -> str:
    """The saved run `compgw demo` shows, or a line saying how to make it."""
    if not SAVED.exists():
        return "(no saved commissioning run: compgw demo --commission runs one live)"
    return SAVED.read_text()
