"""``compgw sim --random-machine SEED | --real-machine NAME [--out DIR]``: write a machine's
files (sim config, truth, gateway config, machine.json) and exit. 0 ok, 1 bad input."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from sim.machine_files import write_machine


def write_machine_dir(seed: int | None, roughness: str, real: str | None, out: str | None) -> int:
    """Draw the random machine of ``seed`` or build the real-data machine ``real``; write it."""
    try:
        if real is not None:
            from sim.real_machines import real_machine

            spec = real_machine(real)
            out_dir = Path(out or f"real-machine-{real}")
        else:
            from sim.random_machine import random_machine

            assert seed is not None
            spec = random_machine(seed, roughness)
            out_dir = Path(out or f"random-machine-{seed}-{roughness}")
        held = [f for f in ("gateway.yaml", "sim.yaml") if (out_dir / f).exists()]
        if held:  # a machine written before, perhaps commissioned since: not overwritten
            raise ValueError(f"{out_dir} already holds a machine ({', '.join(held)}): give "
                             "another --out, or remove it first")  # fmt: skip
        write_machine(spec, out_dir)
    except (ValueError, OSError, KeyError) as err:
        print(f"compgw sim: {err}", file=sys.stderr)
        return 1
    print(f"compgw sim: wrote {out_dir}/sim.yaml, gateway.yaml, machine.json, truth/")
    for line in next_steps(out_dir):
        print(line)
    return 0


def next_steps(out_dir: Path) -> list[str]:
    """What to run next, with the instruments' addresses (from machine.json): a user
    should not have to dig the laser's unit id out of sim.yaml."""
    summary = json.loads((out_dir / "machine.json").read_text(encoding="utf-8"))
    ins = summary.get("instruments", {})
    given = [ins[k]["calibrate"] for k in ("laser", "xy", "delta_a", "temperature")
             if k in ins and "calibrate" in ins[k]]
    return [
        "next, in three terminals:",
        f"  compgw sim -c {out_dir}/sim.yaml",
        f"  compgw run -c {out_dir}/gateway.yaml",
        f"  compgw commission -c {out_dir}/gateway.yaml {' '.join(given)} --dry-run",
        "(commission reloads the gateway through its status unit: set status.remote_control: "
        f"true in {out_dir}/gateway.yaml first, and back to false when done)",
    ]
