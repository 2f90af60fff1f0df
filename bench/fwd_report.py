"""bench/forwarding.py's results: the two sides of a row (direct and through the gateway),
the printed table, the issue-4 verdicts and a profile's summary.

    python bench/fwd_report.py PROFILE.folded [--top 22]   # a kept profile, summarised again
"""

from __future__ import annotations

import argparse
import re
from dataclasses import dataclass, field
from pathlib import Path

from fwd_load import Case


@dataclass
class Side:
    lat: list[float] = field(default_factory=list)
    wall: float = 0.0
    errors: int = 0
    cpu: dict[str, float] = field(default_factory=dict)  # process name -> CPU s

    def add(self, r: dict, cpu: dict[str, float]) -> None:
        self.lat += r["lat"]
        self.wall += r["wall"]
        self.errors += r["errors"]
        self.cpu["load"] = self.cpu.get("load", 0.0) + r["cpu"]
        for k, v in cpu.items():
            self.cpu[k] = self.cpu.get(k, 0.0) + v

    def p(self, q: float) -> float:
        s = sorted(self.lat)
        return s[min(len(s) - 1, int(q / 100 * len(s)))] * 1000 if s else float("nan")

    @property
    def tps(self) -> float:
        return len(self.lat) / self.wall if self.wall else float("nan")

    def cpu_us(self, name: str) -> float:
        return self.cpu.get(name, float("nan")) / max(len(self.lat), 1) * 1e6


@dataclass
class Row:
    transport: str
    case: Case
    masters: int
    direct: Side
    gateway: Side
    note: str = ""


def summarize_folded(path: Path, top: int = 22) -> str:
    """Self and inclusive share of samples per function (file:function, lines merged)."""
    self_n: dict[str, int] = {}
    incl_n: dict[str, int] = {}
    total = 0
    for line in path.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            continue
        n = int(count)
        total += n
        funcs = []
        for frame in stack.split(";"):
            m = re.match(r"(.*?) \((.*?)(?::\d+)?\)$", frame)
            name = f"{Path(m.group(2)).name}:{m.group(1)}" if m else frame
            funcs.append(name)
        self_n[funcs[-1]] = self_n.get(funcs[-1], 0) + n
        for name in set(funcs):
            incl_n[name] = incl_n.get(name, 0) + n
    if not total:
        return f"{path.name}: no samples"
    lines = [f"{path.name}: {total} active samples",
             f"  {'self%':>6}  {'incl%':>6}  function"]
    for name, n in sorted(self_n.items(), key=lambda kv: -kv[1])[:top]:
        lines.append(f"  {100 * n / total:6.1f}  {100 * incl_n[name] / total:6.1f}  {name}")
    lines.append("  inclusive, project code (gateway/*):")
    ours = [(k, v) for k, v in incl_n.items() if "/gateway/" in k or k.split(":")[0] in
            {"upstream.py", "downstream.py", "router.py", "frames.py", "serialline.py",
             "axis.py", "app.py", "compensation.py", "tables.py"}]
    for name, n in sorted(ours, key=lambda kv: -kv[1])[:top]:
        lines.append(f"  {'':6}  {100 * n / total:6.1f}  {name}")
    return "\n".join(lines)


HEADER = (f"{'transport':<9} {'case':<13} {'m':>2} | {'direct p50':>10} {'p99':>6} "
          f"{'tx/s':>6} | {'gw p50':>6} {'p99':>6} {'tx/s':>6} | {'p50x':>5} {'p99x':>5} "
          f"{'tx/sx':>5} | {'+p50':>5} | {'cpu/tx d':>8} {'g':>4} {'gw':>4} | {'err':>3}")


def format_row(r: Row) -> str:
    d, g = r.direct, r.gateway
    d50, d99, g50, g99 = d.p(50), d.p(99), g.p(50), g.p(99)
    gw_key = next((k for k in g.cpu if k not in ("load", "sim", "simB")), "gw")
    d_cpu = sum(d.cpu_us(k) for k in d.cpu)  # load generator + sim
    g_cpu = sum(g.cpu_us(k) for k in g.cpu)  # load generator + sim + gateway
    return (f"{r.transport:<9} {r.case.name:<13} {r.masters:>2} | {d50:>8.3f}ms {d99:>6.3f} "
            f"{d.tps:>6.0f} | {g50:>6.3f} {g99:>6.3f} {g.tps:>6.0f} | {g50 / d50:>5.2f} "
            f"{g99 / d99:>5.2f} {g.tps / d.tps:>5.2f} | {g50 - d50:>5.2f} | "
            f"{d_cpu:>6.0f}µs {g_cpu:>4.0f} {g.cpu_us(gw_key):>4.0f} | "
            f"{d.errors + g.errors:>3}" + (f"  {r.note}" if r.note else ""))


def verdicts(rows: list[Row]) -> list[str]:
    out = []
    for r in rows:
        product_option = "config rtu.t35: exact" in r.note  # `t35: exact` is a config key
        if r.case.extra or (r.note and not product_option):
            continue
        d, g = r.direct, r.gateway
        tag = f"{r.transport} {r.case.name} x{r.masters}" + (" t35:exact" if product_option
                                                              else "")  # fmt: skip
        if r.transport == "tcp":
            checks = [("p50 <= 1.5x", g.p(50) / d.p(50), 1.5, False),
                      ("p99 <= 2x", g.p(99) / d.p(99), 2.0, False)]
            if r.masters == 8:
                checks.append(("tx/s >= 0.6x", g.tps / d.tps, 0.6, True))
        else:
            checks = [("RTU added p50 <= 0.3 ms", g.p(50) - d.p(50), 0.3, False)] \
                if r.masters == 1 else []
        for label, value, limit, at_least in checks:
            ok = value >= limit if at_least else value <= limit
            out.append(f"  {'PASS' if ok else 'MISS'}  {tag:<24} {label:<24} {value:6.2f}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="bench/forwarding.py's profile summary, of "
                                             "folded stacks it kept (--profile)")  # fmt: skip
    ap.add_argument("folded", type=Path, nargs="+", help="a folded-stack file")
    ap.add_argument("--top", type=int, default=22, help="functions listed")
    args = ap.parse_args(argv)
    for path in args.folded:
        print(summarize_folded(path, args.top))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
