"""What a calibrated config leaves on a kept machine with no heat and no scatter: the static
part of the judge's E, split from the heat and noise of its runs.

For a machine kept by ``bench/accuracy.py --keep DIR``: the sim's own truth (its ``Machine``
driven directly, no Modbus) with repeatability, stick-slip, settling and heat taken out,
commanded through the gateway's chain of the calibrated config (``work/gw.yaml``, no thermal
stage). Per axis, at random parks of the other plane axis: the ISO 230-2 bidirectional
deviations at random targets, approached ↑ from below and ↓ from above as the judge does
(so partial take-up and lost motion count), their range (E) and the range of their means
(M); and the same along the pitch line (the other axis at its lower end, where the tables
were measured).

    python bench/static_chain.py /tmp/keep/rough-0 [--parks 10] [--targets 12]
                                 [--bow-step-mm 2]
    python bench/static_chain.py /tmp/keep        # every machine kept, and sums per group
    python bench/static_chain.py /tmp/keep --oracle   # and what a perfect table would leave

``--oracle``: per axis, the same E at random parks with that axis's pitch table, cyclic term
and backlash replaced by one perfect table: the quiet machine's own deviation read every
``ORACLE_STEP_MM`` along the pitch line, ↑ and ↓, through the rest of the calibrated chain.
What it leaves is what no table can take out (the drive's step, the plane away from the
pitch line, the lost motion's take-up); the calibrated table's E less it is what the table
itself misses.

A diagnostic: it imports both ``sim`` and ``gateway`` (the judge does not).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from gateway.calibration.fitting.outputs import write_table
from gateway.compensation import PitchTable
from gateway.config import load_config as load_gateway_config
from gateway.tables import build_chain
from sim.config import parse_config
from sim.machine import Machine


def quiet_sim(sim_yaml: Path) -> Machine:
    """The machine's truth without scatter, stick-slip, settling or heat."""
    data = yaml.safe_load(sim_yaml.read_text())
    for errs in data["sim"]["machine"].values():
        errs["repeatability_um"] = 0.0
        for key in ("stick_slip", "settling", "heat", "thermal"):
            errs.pop(key, None)
    for sensor in ("delta_a", "temperature"):  # they read the heat taken out
        (data["sim"].get("instruments") or {}).pop(sensor, None)
    cfg = parse_config(data, sim_yaml.parent)
    return Machine(cfg.sim, base_dir=str(sim_yaml.parent))


#: the perfect table's spacing (mm): a lead of 4 mm is read 16 times a turn (linear
#: interpolation misses a sine of amplitude a by a·(π/16)²/2, 2 % of a)
ORACLE_STEP_MM = 0.25


class Rig:
    """The quiet machine commanded through a gateway chain (no thermal stage)."""

    def __init__(self, machine: Machine, chain: Any, gw: Any) -> None:
        self.m, self.chain, self.gw = machine, chain, gw
        self.now_s = 0.0
        self.at_mm = {n: float(a.cfg.travel_mm[0]) for n, a in machine.axes.items()}

    def go(self, target_mm: dict[str, float]) -> None:
        """Move every named axis to its nominal target (in turn), corrected by the chain as
        the gateway corrects it (the partner's nominal target for the plane, the direction
        of approach, the drive's whole units)."""
        for name, x in target_mm.items():
            ax = self.gw.axes[name]
            nominal = {a: [round(v / self.gw.axes[a].pulse_mm)] for a, v in
                       {**self.at_mm, **target_mm}.items()}  # fmt: skip
            sim_pulse = self.m.axes[name].cfg.pulse_mm
            direction = {a: [1] for a in nominal}
            direction[name] = [1 if x >= self.at_mm[name] else -1]
            cmd = self.chain.command_mm_batch(nominal, direction)[name][0]
            units = round(cmd / ax.pulse_mm * ax.command_scale)  # what the gateway sends
            pulses = round(units * ax.pulse_mm / ax.command_scale / sim_pulse)
            self.now_s += self.m.begin_move(name, pulses, 50.0, self.now_s) + 0.5
            self.m.update(self.now_s)
            self.at_mm[name] = x

    def start(self) -> None:
        """Every axis to its lower end (approached + from where the drive stands)."""
        for n, x in list(self.at_mm.items()):
            self.go({n: x})

    def deviation_um(self, name: str, x_mm: float) -> float:
        return (self.m.table_mm(name, self.now_s) - x_mm) * 1000.0


def up_and_down_um(rig: Rig, name: str, other: str | None, park: float | None,
                   targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Deviations (µm) of one axis at ``targets``, approached ↑ then ↓, the other axis at
    ``park``."""
    if other is not None and park is not None:
        rig.go({other: park})
    lo, hi = rig.m.axes[name].cfg.travel_mm
    up, down = [], []
    rig.go({name: max(lo, targets[0] - 2.0)})
    for t in targets:
        rig.go({name: float(t)})
        up.append(rig.deviation_um(name, float(t)))
    rig.go({name: min(hi, targets[-1] + 2.0)})
    for t in targets[::-1]:
        rig.go({name: float(t)})
        down.append(rig.deviation_um(name, float(t)))
    return np.array(up), np.array(down[::-1])


def axis_static(rig: Rig, name: str, other: str | None, park: float | None,
                targets: np.ndarray) -> dict[str, float]:  # fmt: skip
    """E and M (µm) of one axis at ``targets``, ↑ then ↓, the other axis at ``park``."""
    u, d = up_and_down_um(rig, name, other, park, targets)
    both = np.concatenate([u, d])
    mean = (u + d) / 2
    return {"E": float(np.ptp(both)), "M": float(np.ptp(mean)), "B": float(np.abs(u - d).max())}


def axis_bow_um(rig: Rig, name: str, other: str | None, park: float | None,
                step_mm: float) -> float:  # fmt: skip
    """The long-wave part of one axis's static miss along the pitch line (µm): the range of
    a degree-4 Chebyshev fit to the bidirectional mean read every ``step_mm``. Heat taken
    off wrongly while commissioning stays in the tables as such a bow (the bench's rough
    screws with heat: 0.5-1.2 µm; the same screws without it: 0.05-0.15 µm)."""
    lo, hi = rig.m.axes[name].cfg.travel_mm
    targets = np.arange(lo + 3, hi - 3, step_mm)
    u, d = up_and_down_um(rig, name, other, park, targets)
    fit = np.polynomial.chebyshev.Chebyshev.fit(targets, (u + d) / 2, 4)
    return float(np.ptp(fit(targets)))


def _rig(machine: Path, gw_path: Path) -> Rig:
    gw = load_gateway_config(gw_path)
    rig = Rig(quiet_sim(machine / "sim.yaml"), build_chain(gw, gw_path.parent), gw)
    rig.start()
    return rig


Draws = list[tuple[float, np.ndarray]]


def _parked_e(rig: Rig, name: str, other: str | None, draws: Draws) -> dict[str, float]:
    """Medians over the ``draws`` (a park of the other axis, targets; the pitch line's park
    is its lower end) of E, M and B (µm)."""
    parked = [axis_static(rig, name, other, park, targets) for park, targets in draws]
    return {k: float(np.median([r[k] for r in parked])) for k in ("E", "M", "B")}


def oracle_e_um(machine: Path, gw_path: Path, name: str, draws: Draws) -> float:
    """E at random parks (median, µm) of axis ``name`` with its pitch table, cyclic term and
    backlash replaced by the quiet machine's own deviation along the pitch line."""
    # beside the config: its tables are named relative to its directory
    path = gw_path.parent / f".oracle-{name}.yaml"
    with tempfile.TemporaryDirectory() as tmp:
        try:
            path.write_text(yaml.safe_dump(oracle_config(machine, gw_path, Path(tmp), [name]),
                                           sort_keys=False))  # fmt: skip
            rig = _rig(machine, path)
            other = next((a for a in rig.m.axes if a != name), None)
            return _parked_e(rig, name, other, draws)["E"]
        finally:
            path.unlink(missing_ok=True)


def oracle_config(machine: Path, gw_path: Path, out_dir: Path,
                  axes: list[str] | None = None) -> dict[str, Any]:  # fmt: skip
    """The config at ``gw_path`` with the pitch table, cyclic term and backlash of ``axes``
    (default: every linear axis) replaced by a perfect table (the quiet machine's own
    deviation read every ``ORACLE_STEP_MM`` along the pitch line, ↑ and ↓, through the
    rest of that config's chain), written into ``out_dir``; the rest (plane, heat) as
    calibrated. What the judge reads
    under it is what no table could cut."""
    data = yaml.safe_load(gw_path.read_text())
    names = axes or [n for n, ax in data["axes"].items() if not ax.get("rotary")]
    for name in names:
        comp = data["axes"][name].setdefault("compensation", {})
        for key in ("pitch", "cyclic", "backlash", "takeup"):
            comp.pop(key, None)
    bare_path = gw_path.parent / ".oracle-bare.yaml"  # beside it: relative tables stay valid
    out_dir.mkdir(parents=True, exist_ok=True)
    try:
        bare_path.write_text(yaml.safe_dump(data, sort_keys=False))
        rig = _rig(machine, bare_path)
        all_axes = list(rig.m.axes)
        for name in names:
            other = next((a for a in all_axes if a != name), None)
            lo, hi = rig.m.axes[name].cfg.travel_mm
            olo = rig.m.axes[other].cfg.travel_mm[0] if other else None
            x = np.linspace(lo, hi, int(np.ceil((hi - lo) / ORACLE_STEP_MM)) + 1)
            up, down = up_and_down_um(rig, name, other, olo, x)
            table = (out_dir / f"{name}_oracle.csv").resolve()
            write_table(table, "csv", PitchTable(x, up * 1e-3, down * 1e-3), "oracle")
            data["axes"][name]["compensation"]["pitch"] = {"file": str(table),
                                                           "interpolation": "linear"}
    finally:
        bare_path.unlink(missing_ok=True)
    return data


def _targets_mm(rng: np.random.Generator, lo_mm: float, hi_mm: float, count: int,
                pulse_mm: float) -> np.ndarray:
    """Random targets 3 mm inside the travel, sorted, on the drive's pulses as the judge's: a
    target between two pulses is commanded at the nearer and read against itself
    (smooth-7's 1 µm pulses: up to ±0.5 µm no table removes, 0.96 µm of E under a perfect
    table)."""
    raw = rng.uniform(lo_mm + 3, hi_mm - 3, count)
    return np.sort(np.round(raw / pulse_mm) * pulse_mm)


def machine_static(machine: Path, config: Path | None, parks: int, targets: int, seed: int,
                   bow_step_mm: float, oracle: bool = False
                   ) -> dict[str, dict[str, float]]:  # fmt: skip
    """Per axis of one kept machine: E on the pitch line, E at random parks (medians of
    ``parks``), with ``bow_step_mm`` the bow, with ``oracle`` E at the same parks under a
    perfect table (µm); printed as it goes."""
    gw_path = config or machine / "work" / "gw.yaml"
    rig = _rig(machine, gw_path)
    rng = np.random.default_rng(seed)
    names = list(rig.m.axes)
    out: dict[str, dict[str, float]] = {}
    for name in names:
        others = [a for a in names if a != name]
        other = others[0] if others else None
        lo, hi = rig.m.axes[name].cfg.travel_mm
        olo, ohi = (rig.m.axes[other].cfg.travel_mm if other else (0.0, 0.0))
        pulse_mm = rig.gw.axes[name].pulse_mm
        line = [(olo, _targets_mm(rng, lo, hi, targets, pulse_mm)) for _ in range(parks)]
        med = _parked_e(rig, name, other, line)
        draws = [(float(rng.uniform(olo + 1, ohi - 1)),
                  _targets_mm(rng, lo, hi, targets, pulse_mm)) for _ in range(parks)]
        pmed = _parked_e(rig, name, other, draws)
        out[name] = {"line": med["E"], "parks": pmed["E"]}
        extra = ""
        if bow_step_mm > 0:
            out[name]["bow"] = axis_bow_um(rig, name, other, olo, bow_step_mm)
            extra += f"; bow {out[name]['bow']:.2f} µm"
        if oracle:
            out[name]["oracle"] = oracle_e_um(machine, gw_path, name, draws)
            extra += f"; a perfect table {out[name]['oracle']:.2f} µm at the same parks"
        print(f"{machine.name} {name}: on the pitch line E {med['E']:.2f} M {med['M']:.2f}"
              f" B {med['B']:.2f} µm; at random parks E {pmed['E']:.2f} M {pmed['M']:.2f} "
              f"B {pmed['B']:.2f} µm (medians of {parks}){extra}", flush=True)  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("machine", type=Path,
                        help="a machine directory kept by accuracy.py, or the --keep directory "
                             "(every machine in it, and the sums per group)")  # fmt: skip
    parser.add_argument("--config", type=Path, help="gateway config (default work/gw.yaml)")
    parser.add_argument("--parks", type=int, default=10)
    parser.add_argument("--targets", type=int, default=12)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--bow-step-mm", type=float, default=0.0,
                        help="also the long-wave bow along the pitch line, read this often")
    parser.add_argument("--oracle", action="store_true",
                        help="also E under a perfect table at the same parks")
    args = parser.parse_args()
    if (args.machine / "sim.yaml").exists():
        machine_static(args.machine, args.config, args.parks, args.targets, args.seed,
                       args.bow_step_mm, args.oracle)  # fmt: skip
        return
    sums: dict[str, dict[str, float]] = {}
    for machine in sorted(d for d in args.machine.iterdir() if (d / "work" / "gw.yaml").exists()):
        group = machine.name.split("-")[0]  # smooth, rough, real
        for axis in machine_static(machine, None, args.parks, args.targets, args.seed,
                                   args.bow_step_mm, args.oracle).values():  # fmt: skip
            into = sums.setdefault(group, {"axes": 0.0})
            into["axes"] += 1
            for key, value in axis.items():
                into[key] = into.get(key, 0.0) + value
    for group, total in sums.items():
        figures = ", ".join(f"{k} {v:.2f}" for k, v in total.items() if k != "axes")
        print(f"{group}: summed over {total['axes']:.0f} axes (µm): {figures}")


if __name__ == "__main__":
    main()
