"""The instrument kinds a technician owns, each through the one interface: a recording's
stops found and aligned with the plan (and every way a recording goes wrong refused with one
line naming the file and stop), a capture export matched row by row, a bridge over TCP and
as a child process (and one that hangs or answers garbage), a gauge typed at the prompt.

The recordings here are made by the test itself (moves at a speed, dwells, ringing, noise),
not by the sim: the sim's own recorder is tested in tests/test_sim_recorder.py.
"""

from __future__ import annotations

import asyncio
import io
import re
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

from gateway.instruments.base import InstrumentError
from gateway.instruments.bridge import CommandBridge, TcpBridge, parse_read_answer
from gateway.instruments.capture import CaptureError, PlanStop, load_layout, read_export
from gateway.instruments.manual import Manual
from gateway.instruments.recording import (
    RecordingError,
    align,
    matched,
    plan_stops,
    read_csv_series,
    read_recording,
    read_rtx,
)
from gateway.instruments.spec import parse_instrument

ROOT = Path(__file__).resolve().parents[1]
DWELL_S = 2.0
RATE_HZ = 1000.0


def iso_targets() -> np.ndarray:
    up = np.arange(0.0, 401.0, 50.0)
    return np.concatenate([up, up[::-1]])  # one bidirectional run


def truth_um(target_mm: np.ndarray) -> np.ndarray:
    """The machine's error at each stop (µm): what the readings must show."""
    return 8.0 * np.sin(target_mm / 70.0) + 0.01 * target_mm


def synthesize(targets_mm: np.ndarray, *, speed_mm_s: float = 200.0, dwell_s: float = DWELL_S,
               rate_hz: float = RATE_HZ, zero_mm: float = 12.345, seed: int = 1,
               pause_at: float | None = None, pause_short_mm: float | None = None
               ) -> np.ndarray:  # fmt: skip
    """A laser's reading (µm, zeroed at ``zero_mm``): a still start, each move at
    ``speed_mm_s`` with vibration, ringing after the stop, a dwell, noise; ``pause_at``:
    a pause of a dwell's length halfway through that move (index), or ``pause_short_mm``
    short of its target."""
    rng = np.random.default_rng(seed)
    out: list[np.ndarray] = []
    here = targets_mm[0] + truth_um(targets_mm[:1])[0] / 1000.0

    def still(at_mm: float, seconds: float) -> None:
        n = int(seconds * rate_hz)
        t = np.arange(n) / rate_hz
        ring = 2.0e-3 * np.exp(-t / 0.03) * np.sin(2 * np.pi * 35 * t)
        out.append(at_mm + ring + rng.normal(0, 2e-5, n))

    def move(a_mm: float, b_mm: float) -> None:
        n = max(2, int(abs(b_mm - a_mm) / speed_mm_s * rate_hz))
        path = np.linspace(a_mm, b_mm, n)
        out.append(path + 3e-4 * np.sin(np.arange(n) / rate_hz * 2 * np.pi * 40))

    still(here, 1.0)
    for i, target in enumerate(targets_mm):
        there = target + truth_um(np.array([target]))[0] / 1000.0
        if i:
            if pause_at == i:
                mid = (here + there) / 2 if pause_short_mm is None else \
                    there - np.sign(there - here) * pause_short_mm  # fmt: skip
                move(here, mid)
                still(mid, dwell_s)
                move(mid, there)
            elif target == targets_mm[i - 1]:  # a reversal: past the target and back
                move(here, here + 2.0)
                move(here + 2.0, there)
            else:
                move(here, there)
        still(there, dwell_s)
        here = there
    return (np.concatenate(out) - zero_mm) * 1000.0


def write_rtx(path: Path, samples: np.ndarray, rate_hz: float = RATE_HZ,
              count: int | None = None, eof: bool = True) -> Path:  # fmt: skip
    head = ("HEADER::\r\nOwner: CARTO-Dynamic\r\nVersion no: 3.0\r\nFile Type: Dynamic\r\n"
            f"Sample rate: {rate_hz:g}\r\nSample no: {samples.size if count is None else count}"
            f"\r\nActual sample rate: {rate_hz:.3f}\r\nTrigger interval: 1\r\n"
            "Date: 28/11/2026 20:00:00\r\nAxis: X\r\nData:\r\n")
    body = struct.pack(f"<{samples.size}d", *samples)
    path.write_bytes(head.encode() + body + (b"EOF::\r\n" if eof else b""))
    return path


def readings(path: Path, targets: np.ndarray, unit: str = "um", sign: float = 1.0
             ) -> np.ndarray:  # fmt: skip
    rec = read_recording(path, unit)
    return align(rec, plan_stops(rec, targets.size, DWELL_S), targets, sign)


# -- recordings --------------------------------------------------------------------------------
def test_rtx_and_csv_recordings_give_the_errors_at_the_stops(tmp_path: Path):
    targets = iso_targets()
    samples = synthesize(targets)
    expected = targets + (truth_um(targets) - truth_um(targets[:1])) / 1000.0
    got = readings(write_rtx(tmp_path / "iso-X.rtx", samples), targets)
    assert np.max(np.abs(got - expected)) * 1000 < 0.05  # µm: noise, ringing left out
    # the CSV time series: value first, time in ms, with a clock offset
    t_ms = 123456.0 + np.arange(samples.size)
    lines = ["Reading (um),Time (ms)"] + [f"{v:.5f},{t:.1f}" for v, t in zip(samples, t_ms)]
    (tmp_path / "iso-X.csv").write_text("\n".join(lines))
    got_csv = readings(tmp_path / "iso-X.csv", targets)
    assert np.max(np.abs(got_csv - expected)) * 1000 < 0.05


def test_a_fast_recording_is_read_in_time(tmp_path: Path):
    targets = iso_targets()[:6]
    samples = synthesize(targets, rate_hz=20_000.0)
    got = readings(write_rtx(tmp_path / "fast.rtx", samples, 20_000.0), targets)
    expected = targets + (truth_um(targets) - truth_um(targets[:1])) / 1000.0
    assert np.max(np.abs(got - expected)) * 1000 < 0.05


@pytest.mark.parametrize(("case", "words"), [
    ("truncated", r"truncated: it does not end with 'EOF::'"),
    ("half-sample", r"not a whole number of 8-byte values"),
    ("count", r"'Sample no' is 999 but the data hold"),
    ("rate", r"stops last 0\.\d+ s by its sample rate \(10000 Hz\) where compgw stood still 2 "
             r"s at each: the rate disagrees with the data \(about 9\d\d Hz would fit\)"),
    ("missing", r"found 17 stops, expected 18: stop 5 .* reads \+2(49|50)\.\d+ mm from the first, "
                r"the plan's stop 5 is \+200\.0000 mm from it \(a stop missing before it\?\)"),
    ("extra", r"found 19 stops, expected 18: stop 5 .* reads \+150\.\d+ mm from the first, "
              r"the plan's stop 5 is \+200\.0000 mm .*pause mid-move"),
    ("sign", r"the steps read -1 x the plan's: the sign is reversed .*give the sign -1"),
    ("unit", r"found 0 stops, expected 18: the values look like µm declared as mm"),
    ("other-axis", r"found \d+ stops, expected 18: the steps read .* the stops do not follow "
                   r"this plan \(another axis's recording"),
])
def test_a_recording_that_does_not_match_is_refused_naming_file_and_stop(tmp_path: Path,
                                                                        case: str, words: str):
    targets = iso_targets()
    samples = synthesize(targets)
    path, unit = tmp_path / "iso-X.rtx", "um"
    if case == "truncated":
        data = write_rtx(path, samples).read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif case == "half-sample":
        data = write_rtx(path, samples, eof=False).read_bytes()
        path.write_bytes(data[:-3] + b"EOF::\r\n")
    elif case == "count":
        write_rtx(path, samples, count=999)
    elif case == "rate":
        write_rtx(path, samples, rate_hz=10_000.0)
    elif case == "missing":  # the stop at 200 mm cut to a blink
        short = synthesize(targets, dwell_s=DWELL_S)
        at = int((1.0 + 4 * DWELL_S + 4 * 50.0 / 200.0) * RATE_HZ)
        write_rtx(path, np.delete(short, np.s_[at + 50 : at + int(DWELL_S * RATE_HZ) - 50]))
    elif case == "extra":  # a pause 0.1 mm short of 150 mm: which stop is its reading?
        write_rtx(path, synthesize(targets, pause_at=3, pause_short_mm=0.1))
    elif case == "sign":
        write_rtx(path, -samples)
    elif case == "unit":
        write_rtx(path, samples)
        unit = "mm"
    else:  # a recording of Y (0..300 in 60 mm steps) given for X's plan
        y = np.concatenate([np.arange(0.0, 301.0, 60.0), np.arange(300.0, -1.0, -60.0)])
        write_rtx(path, synthesize(y))
    with pytest.raises(RecordingError, match=words) as err:
        readings(path, targets, unit)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_a_reversed_laser_is_read_with_its_sign(tmp_path: Path):
    targets = iso_targets()
    path = write_rtx(tmp_path / "iso-X.rtx", -synthesize(targets))
    got = readings(path, targets, sign=-1.0)
    expected = targets + (truth_um(targets) - truth_um(targets[:1])) / 1000.0
    assert np.max(np.abs(got - expected)) * 1000 < 0.05


def test_csv_series_errors_name_the_line(tmp_path: Path):
    path = tmp_path / "s.csv"
    path.write_text("time_s,um\n0.000,1\n0.001,x\n")
    with pytest.raises(RecordingError, match=r"s\.csv: line 3: .* not a time and a number"):
        read_csv_series(path, "um")
    path.write_text("time_s,um\n0.002,1\n0.001,2\n")
    with pytest.raises(RecordingError, match=r"line 3: time 0\.001 s does not follow"):
        read_csv_series(path, "um")
    with pytest.raises(ValueError, match="unit 'furlong'"):
        read_rtx(path, "furlong")


def test_a_csv_series_reads_alike_plain_quoted_with_blank_rows_and_columns_swapped(
        tmp_path: Path):  # fmt: skip
    """numpy's parser reads the plain file (hours at 500 Hz: millions of rows); a quoted or
    ragged one is read row by row, to the same numbers."""
    t = np.arange(0.0, 2.0, 0.002)
    v = 1000.0 * np.sin(t)
    plain = tmp_path / "plain.csv"
    plain.write_text("time_s,position_um\n" + "".join(f"{a:.3f},{b:.4f}\n" for a, b in zip(t, v)))
    other = tmp_path / "other.csv"
    other.write_text('"position_um","time_ms"\n\n' + "".join(
        f'"{b:.4f}","{1000 * a:.0f}"\n' for a, b in zip(t, v)))  # fmt: skip
    a, b = read_csv_series(plain, "um"), read_csv_series(other, "um")
    assert a.t_s.size == b.t_s.size == t.size and a.rate_hz == pytest.approx(500.0)
    assert np.allclose(a.t_s, b.t_s) and np.allclose(a.value_mm, b.value_mm)
    assert np.allclose(a.value_mm, v / 1000.0, atol=1e-7)


# -- capture exports ----------------------------------------------------------------------------
def plan_stops_of(targets: np.ndarray) -> list[PlanStop]:
    half = targets.size // 2
    return [PlanStop(float(t), 1, +1 if i < half else -1) for i, t in enumerate(targets)]


def export(path: Path, targets: np.ndarray, dev_um: np.ndarray, dirs: list[str]) -> Path:
    rows = ["Point,Target (mm),Run,Dir,Error (um)"]
    rows += [f"{i + 1},{t:.3f},1,{d},{e:.3f}" for i, (t, e, d) in enumerate(zip(targets, dev_um,
                                                                                  dirs))]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_capture_export_is_matched_with_the_plan_row_by_row(tmp_path: Path):
    layout = load_layout(ROOT / "config" / "capture-generic.yaml")
    targets = iso_targets()
    plan = plan_stops_of(targets)
    dirs = ["+" if s.direction > 0 else "-" for s in plan]
    dev = truth_um(targets)
    got = read_export(export(tmp_path / "cap.csv", targets, dev, dirs), layout, plan)
    assert np.allclose(got, targets + np.round(dev, 3) / 1000.0)
    # one row too few: refused, naming the first row that is not the plan's
    path = export(tmp_path / "short.csv", np.delete(targets, 4), np.delete(dev, 4),
                  dirs[:4] + dirs[5:])
    with pytest.raises(CaptureError, match=r"short\.csv: 17 readings, the plan has 18: line 6 "
                                           r"\(reading 5\) is at 250\.0000 mm where the plan's "
                                           r"reading 5 is at 200\.0000 mm"):
        read_export(path, layout, plan)
    path = export(tmp_path / "long.csv", np.append(targets, 0.0), np.append(dev, 0.0),
                  [*dirs, "-"])
    with pytest.raises(CaptureError, match=r"19 readings, the plan has 18: line 20 is one more"):
        read_export(path, layout, plan)
    wrong = dirs.copy()
    wrong[12] = "+"
    with pytest.raises(CaptureError, match=r"line 14 \(reading 13\) was approached \+, the "
                                           r"plan's from the - side"):
        read_export(export(tmp_path / "dir.csv", targets, dev, wrong), layout, plan)
    cut = export(tmp_path / "cut.csv", targets[:10], dev[:10], dirs[:10])
    with pytest.raises(CaptureError, match=r"the plan's reading 11 at 350\.0000 mm \(run 1\) "
                                           r"is missing"):
        read_export(cut, layout, plan)


def test_a_mapping_file_error_names_the_key(tmp_path: Path):
    path = tmp_path / "m.yaml"
    path.write_text("target_column: T\nreading_column: R\nreading_is: offset\n")
    with pytest.raises(CaptureError, match=r"m\.yaml: reading_is: Input should be"):
        load_layout(path)
    path.write_text("target_column: T\nreading_column: R\nreading_unit: furlong\n")
    with pytest.raises(CaptureError, match="reading_unit: unit 'furlong'"):
        load_layout(path)


# -- the option syntax -------------------------------------------------------------------------
def test_one_option_syntax_for_every_kind():
    assert parse_instrument("--laser", "127.0.0.1:5020:20").kind == "modbus"
    m = parse_instrument("--laser", "modbus:127.0.0.1:5020:20:7")
    assert (m.host, m.port, m.unit_id, m.address) == ("127.0.0.1", 5020, 20, 7)
    b = parse_instrument("--laser", "bridge:tcp:127.0.0.1:7000")
    assert (b.kind, b.transport, b.port) == ("bridge", "tcp", 7000)
    c = parse_instrument("--laser", "bridge:cmd:python3 my_bridge.py --port COM3:19200")
    assert c.command == "python3 my_bridge.py --port COM3:19200"
    r = parse_instrument("--laser", "recording:/data/laser:mm:-1")
    assert (r.kind, str(r.directory), r.unit, r.sign, r.reads_later) == (
        "recording", "/data/laser", "mm", -1, True)
    cap = parse_instrument("--laser", "capture:generic.yaml:/data")
    assert (cap.kind, cap.mapping.name, cap.reads_later) == ("capture", "generic.yaml", True)
    man = parse_instrument("--laser", "manual:deviation")
    assert (man.kind, man.unit, man.deviation) == ("manual", "um", True)
    for bad, words in [("127.0.0.1:5020", "give HOST:PORT:UNIT"),
                       ("bridge:udp:1", "bridge:tcp:HOST:PORT or bridge:cmd"),
                       ("recording:d:furlong", "unit 'furlong'"),
                       ("recording:d:um:2", "sign '2'"),
                       ("capture:only.yaml", "capture:MAPPING.yaml:DIR")]:
        with pytest.raises(ValueError, match=words) as err:
            parse_instrument("--laser", bad)
        assert str(err.value).startswith(f"--laser {bad!r}")


# -- bridges ---------------------------------------------------------------------------------------
def test_bridge_answers_are_checked_field_by_field():
    assert parse_read_answer("OK 12.5 um STABLE", ["X"]).values == (12.5,)
    assert not parse_read_answer("OK 1 2 mm MOVING", ["X", "Y"]).stable
    for line, words in [("ERR beam lost", "the bridge says: beam lost"),
                        ("OK banana um STABLE", "'banana' in 'OK banana um STABLE' is not a"),
                        ("OK 1 furlong STABLE", "unit 'furlong'"),
                        ("OK 1 um READY", "'READY' .* is not STABLE or MOVING"),
                        ("hello", "answer 'hello' is not 'OK V UNIT STABLE|MOVING'")]:
        with pytest.raises(InstrumentError, match=words):
            parse_read_answer(line, ["X"])


async def _serve(answers: dict[str, list[str]], hang_on: str | None = None):
    """A TCP bridge answering from ``answers`` (request -> answers in turn)."""

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while line := await reader.readline():
            request = line.decode().strip()
            if request == hang_on:
                await asyncio.sleep(30)
            queue = answers.get(request) or ["ERR unknown request"]
            writer.write((queue.pop(0) if len(queue) > 1 else queue[0]).encode() + b"\n")
            await writer.drain()
        writer.close()

    return await asyncio.start_server(handle, "127.0.0.1", 0)


def test_a_tcp_bridge_is_read_until_stable_and_its_failures_named():
    async def body() -> None:
        server = await _serve({"HELLO 1": ["OK test-laser channels=X"],
                               "READ X": ["OK 100.0 um MOVING", "OK 1234.5 um STABLE"],
                               "READ Y": ["OK banana um STABLE"], "BYE": ["OK"]},
                              hang_on="READ Z")
        port = server.sockets[0].getsockname()[1]
        laser = TcpBridge("laser", "127.0.0.1", port, {"A": "Z"}, timeout_s=0.3, poll_s=0.0)
        try:
            assert await laser.read_mm(["X"]) == {"X": pytest.approx(1.2345)}
            with pytest.raises(InstrumentError, match=r"laser \(bridge tcp 127\.0\.0\.1:\d+\): "
                                                      r"READ Y: 'banana'"):
                await laser.read_mm(["Y"])
            with pytest.raises(InstrumentError, match=r"READ Z: no answer within 0\.3 s \(the "
                                                      "bridge hangs: stopped\\)"):
                await laser.read_mm(["A"])
            assert await laser.read_mm(["X"]) == {"X": pytest.approx(1.2345)}  # reconnects
        finally:
            await laser.close()
            server.close()
            await server.wait_closed()
        nobody = TcpBridge("laser", "127.0.0.1", port, timeout_s=0.3)
        with pytest.raises(InstrumentError, match="cannot connect"):
            await nobody.read_mm(["X"])

    asyncio.run(asyncio.wait_for(body(), 20))


BRIDGE_SCRIPT = """
import sys
n = 0
for line in sys.stdin:
    words = line.split()
    if words[0] == "HELLO":
        print("OK script-bridge channels=X", flush=True)
    elif words[0] == "READ":
        n += 1
        if n == 3:
            print("oops: a traceback", file=sys.stderr, flush=True)
            sys.exit(4)
        print(f"OK {n * 0.5} mm STABLE", flush=True)
    else:
        print("OK", flush=True)
        break
"""


def test_a_child_process_bridge_and_one_that_exits(tmp_path: Path):
    script = tmp_path / "bridge.py"
    script.write_text(BRIDGE_SCRIPT)

    async def body() -> None:
        laser = CommandBridge("laser", f"{sys.executable} {script}", timeout_s=5.0, retries=0)
        try:
            assert await laser.read_mm(["X"]) == {"X": 0.5}
            assert await laser.read_mm(["X"]) == {"X": 1.0}
            with pytest.raises(InstrumentError, match=r"the bridge exited \(code 4\); its last "
                                                      r"words: 'oops: a traceback'"):
                await laser.read_mm(["X"])
        finally:
            await laser.close()

    asyncio.run(asyncio.wait_for(body(), 20))


# -- manual entry ----------------------------------------------------------------------------------
def test_manual_entry_validates_and_reads_again():
    typed = io.StringIO("twelve\n0.0123\n\n"  # a word, then a deviation, Enter
                        "900\n900\nr\n-8,5\n\n")  # far: typed twice; read again; a comma
    said: list[str] = []
    gauge = Manual("gauge", "um", deviation=True, stdin=typed, say=said.append)

    async def body() -> None:
        first = await gauge.read_mm(["X"], {"X": 100.0})
        second = await gauge.read_mm(["X"], {"X": 200.0})
        assert first == {"X": pytest.approx(100.0000123)}
        assert second == {"X": pytest.approx(199.9915)}
        with pytest.raises(InstrumentError, match=r"gauge \(manual deviation in um\): no more "
                                                  "input"):
            await gauge.read_mm(["X"], {"X": 300.0})

    asyncio.run(body())
    text = "".join(said)
    assert "'twelve' is not a number" in text
    assert "900 um is 0.900 mm from the target, more than the 0.5 mm" in text
    assert "X at 200.0000 mm: the gauge's deviation in um?" in text


def test_a_pause_mid_move_is_left_out(tmp_path: Path):
    """The computer stalled halfway between two targets (or at an approach point): the
    recording shows the axis standing there, at none of the plan's steps. Left out, as a
    laser's own capture leaves standstill outside its targets' windows; the stops that are
    the plan's give its readings. (A stall of 40 ms on a loaded machine made the suite's
    recorded commissioning find 151 stops for 150.) Three pauses in a plan of 18: too many
    to be stalls, refused."""
    targets = iso_targets()
    expected = targets + (truth_um(targets) - truth_um(targets[:1])) / 1000.0
    for at in (3, 11):
        got = readings(write_rtx(tmp_path / f"iso-{at}.rtx", synthesize(targets, pause_at=at)),
                       targets)  # fmt: skip
        assert np.max(np.abs(got - expected)) * 1000 < 0.05, at
    short = synthesize(targets, pause_at=10, pause_short_mm=2.0)  # 2 mm short: an approach
    rec = read_recording(write_rtx(tmp_path / "iso-approach.rtx", short), "um")
    said: list[str] = []
    got = matched(rec, plan_stops(rec, targets.size, DWELL_S), targets, say=said.append)
    got = got - got[0] + targets[0]
    assert np.max(np.abs(got - expected)) * 1000 < 0.05
    assert len(said) == 1 and re.search(r"iso-approach\.rtx: the stop at [\d.]+ s \(\+35[12]\.\d+ "
                                        r"mm from the first\) is at none of the plan's steps: "
                                        r"a pause mid-move, left out", said[0]), said  # fmt: skip
    moves = np.concatenate([targets[:5], [125.0], targets[5:9], [425.0, 380.0], targets[9:]])
    with pytest.raises(RecordingError, match=r"found 21 stops, expected 18"):
        readings(write_rtx(tmp_path / "iso-3.rtx", synthesize(moves)), targets)


def test_the_machine_standing_before_and_after_the_plan_is_not_an_extra_stop(tmp_path: Path):
    """The laser's recording started before compgw's first move and stopped after its last:
    the still stretches at both ends are not the plan's, and are left out."""
    targets = iso_targets()
    samples = synthesize(np.concatenate([[-20.0], targets, [60.0]]))  # stands before, after
    got = readings(write_rtx(tmp_path / "iso-X.rtx", samples), targets)
    expected = targets + (truth_um(targets) - truth_um(targets[:1])) / 1000.0
    assert np.max(np.abs(got - expected)) * 1000 < 0.05
