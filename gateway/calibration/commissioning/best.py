"""``compgw commission``'s best tables (kept for :mod:`.rounds`): each
round's verification score of an axis or the plane, the files (and the table's
interpolation) of the best judged so far kept aside, and put back when a refinement does
not pay or the budget ends a round before it was judged.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from ...formats import atomic_write_text
from ..fitting import adaptive
from ..fitting.plane_frame import FITTED_FILE, FRAME_FILE

if TYPE_CHECKING:
    from .axes import Axes
    from .record import Record

def table_files(record: Record, name: str) -> list[Path]:
    """The files that hold an axis's table (or, for "XY", the planar model); none where it
    has none yet."""
    if name == "XY":
        if record.tables.planar_model is None:
            return []
        model = record.config_dir / str(record.tables.planar_model)
        return [model, model.parent / "xy_points.csv", model.parent / FRAME_FILE,
                model.parent / FITTED_FILE]
    files = []
    if name in record.tables.pitch:
        files.append(record.config_dir / record.tables.pitch[name])
    if name in record.tables.cyclic:  # refinement scans add cyclic stations too
        files.append(record.config_dir / record.tables.cyclic[name])
    return files


def copy_aside(record: Record, name: str, keep: Path) -> None:
    """An axis's (or the plane's) table files as they are now, copied into ``keep``."""
    keep.mkdir(parents=True, exist_ok=True)
    for path in table_files(record, name):
        if path.exists():
            shutil.copyfile(path, keep / f"{name}-{path.name}")
        else:  # (a plane without a frame): no older copy stands in for it
            (keep / f"{name}-{path.name}").unlink(missing_ok=True)


def put_back_files(record: Record, name: str, keep: Path) -> bool:
    """The files :func:`copy_aside` kept in ``keep`` copied over the current ones, and one
    that did not exist then removed; True when any differed."""
    changed = False
    for path in table_files(record, name):
        saved = keep / f"{name}-{path.name}"
        if saved.exists() and (not path.exists() or path.read_bytes() != saved.read_bytes()):
            atomic_write_text(path, saved.read_text())
            changed = True
        elif not saved.exists() and path.exists():
            path.unlink()
            changed = True
    return changed


class BestTables:
    """The best tables judged so far, per axis and for the plane ("XY")."""

    def __init__(self, axes: Axes, record: Record) -> None:
        self.axes = axes
        self.record = record

    def restore_best(self) -> None:
        """Put back the best table of every axis (and the plane's model) judged so far."""
        for name in self.record.state.get("best", {}):
            if self._put_back(name):
                self.record.state["notes"].append(f"{name}: back to its best "
                                           f"(round {self.record.state['best'][name]['round']})")

    def _put_back(self, name: str) -> bool:
        """The best files of an axis (or "XY") as they were: copied over the current ones,
        and one that did not exist then removed (a plane's frame, where the best plane was
        pinned without a fade), and the table's interpolation then; True when any
        differed."""
        keep = self.record.dir / "tables" / "best"
        changed = False
        method = self.record.state.get("best", {}).get(name, {}).get("interpolation")
        if method is not None and method != self.record.tables.interpolation.get(name, "linear"):
            if method == "linear":
                self.record.tables.interpolation.pop(name, None)
            else:
                self.record.tables.interpolation[name] = method
            changed = True
        return put_back_files(self.record, name, keep) or changed

    def read_again(self, name: str, score: float, r: int) -> float:
        """Round ``r`` verified an axis's best table again, unchanged (at other random
        targets): its score is the mean of every verification of that table, not the least
        of them. The least is the luckiest draw of the scatter: rough-0 Y read 1.94 µm
        (within 2) in round 1 and 2.63 µm on the same table in round 2, was kept at 1.94
        and settled unrefined; the judge then read E 1.65 µm where the runs that refined it
        read 0.54-1.03. Returns the new score."""
        best = self.record.state["best"][name]
        if best.get("reads_round") == r:  # this round again, resumed: counted already
            return float(best["score"])
        reads = [*best.get("reads", [best["score"]]), score]
        best.update(reads=reads, reads_round=r, score=float(sum(reads) / len(reads)))
        return float(best["score"])

    def keep_best(self, name: str, score: float, r: int, rms: float | None = None,
                   swept: bool = False, noise: float = 0.0) -> bool:  # fmt: skip
        """Record round ``r``'s verification score (µm) of an axis or the plane (``swept``:
        the axis was swept in the round before). A score
        that :func:`..fitting.adaptive.keeps_refinement` keeps makes the current table the best
        (copied aside); else the best is put back. False when it was put back. The plane
        is kept or put back on its RMS vector error (``rms``) where both rounds have one:
        its score, the largest error at 32 points read once, moves by more than the 10 %
        between two readings of the same field (sdss-2130: 4.83 → 5.37 µm, RMS 2.85 →
        2.66, and its denser grid was put back for good)."""
        best = self.record.state["best"]
        keep = self.record.dir / "tables" / "best"
        keep.mkdir(parents=True, exist_ok=True)
        old = best.get(name)
        if old is not None and old["round"] == r:  # this round again, resumed: as it was
            return True
        now, was = score, None if old is None else old["score"]
        if rms is not None and old is not None and old.get("rms") is not None:
            now, was = rms, old["rms"]
        if was is None or adaptive.keeps_refinement(now, was, plane=name == "XY",
                                                      swept=swept, noise_um=noise):  # fmt: skip
            best[name] = {"score": score, "round": r, **({"rms": rms} if rms is not None
                                                          else {})}  # fmt: skip
            # and how it is read
            if name in self.record.tables.pitch and not self.axes.rotary(name):
                best[name]["interpolation"] = self.record.tables.interpolation.get(name, "linear")
            copy_aside(self.record, name, keep)
            return True
        self._put_back(name)
        return False

