# ruff: noqa: E501  (a table of cases reads best one case per line)
"""Config validation: every bad config is refused with one line naming the YAML path."""

from __future__ import annotations

import copy
import re
from pathlib import Path

import pytest
import yaml

from gateway.config import ConfigError, load_config, parse_config, warnings

BASE = {
    "upstream": {"tcp": {"host": "127.0.0.1", "port": 5020}},
    "buses": {"line1": {"tcp": {"host": "127.0.0.1", "port": 5021}, "timeout_s": 0.1}},
    "axes": {
        "X": {
            "bus": "line1",
            "unit": 1,
            "pulse_mm": 0.001,
            "travel_mm": [0, 800],
            "registers": {
                "target": {"address": 0x6201, "order": "hi_lo"},
                "feedback": {"address": 0x602A},
                "status": {"address": 0x1003, "homed_bit": 6},
                "trigger": {"address": 0x6002, "value": 0x10},
            },
            "compensation": {"backlash_mm": 0.01, "max_correction_mm": 0.2},
        },
        "Y": {
            "bus": "line1",
            "unit": 2,
            "pulse_mm": 0.001,
            "travel_mm": [0, 600],
            "registers": {"target": {"address": 0x6201}, "feedback": {"address": 0x602A}},
        },
    },
    "thermal_sources": {
        "x_ref": {"bus": "line1", "unit": 10, "register": {"address": 0}, "scale_mm": 0.001}
    },
    "status": {"upstream_unit": 247},
}


def with_change(path: str, value):
    data = copy.deepcopy(BASE)
    keys = path.split(".")
    node = data
    for key in keys[:-1]:
        node = node[int(key) if isinstance(node, list) else key]
    if value is _DELETE:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return data


_DELETE = object()

BAD = [
    ("axes.X.registers.target.address", 70000, r"axes\.X\.registers\.target\.address: 70000 is not in 0\.\.65535"),
    ("axes.X.registers.target.order", "big", r"axes\.X\.registers\.target\.order: 'big'"),
    ("axes.X.registers.target.words", 3, r"axes\.X\.registers\.target\.words: 3"),
    ("axes.X.registers.feedback.counts_per_pulse", 0, r"axes\.X\.registers\.feedback\.counts_per_pulse: 0 must be > 0"),
    ("axes.X.registers.feedback.table", "coil", r"axes\.X\.registers\.feedback\.table: 'coil'"),
    ("axes.X.registers.status.homed_bit", 16, r"axes\.X\.registers\.status\.homed_bit: 16 is not in 0\.\.15"),
    ("axes.X.registers.trigger.rising_bit", 3, r"axes\.X\.registers\.trigger: .*value or rising_bit"),
    ("axes.X.registers.feedback.address", 0x6202, r"axes\.X\.registers: .*overlap"),
    ("axes.X.registers.target", _DELETE, r"axes\.X\.registers\.target: missing"),
    ("axes.X.unit", 0, r"axes\.X\.unit: 0 is not in 1\.\.247"),
    ("axes.X.unit", 248, r"axes\.X\.unit: 248 is not in 1\.\.247"),
    ("axes.X.unit", "one", r"axes\.X\.unit: 'one'"),
    ("axes.X.upstream_unit", 2, r"axes\.Y: 2 upstream unit already used by axes\.X"),
    ("axes.X.bus", "line9", r"axes\.X\.bus: 'line9' is not one of buses: line1"),
    ("axes.X.pulse_mm", -0.001, r"axes\.X\.pulse_mm: -0\.001 must be > 0"),
    ("axes.X.pulse_mm", _DELETE, r"axes\.X\.pulse_mm: missing"),
    ("axes.X.travel_mm", [800, 0], r"axes\.X\.travel_mm: .*low < high"),
    ("axes.X.travel_mm", [0], r"axes\.X\.travel_mm"),
    ("axes.X.home_direction", 0, r"axes\.X\.home_direction: 0"),
    ("axes.X.speed", 5, r"axes\.X\.speed: unknown key"),
    ("axes.X.compensation.backlash_mm", -0.01, r"axes\.X\.compensation\.backlash_mm: -0\.01"),
    ("axes.X.compensation.max_correction_mm", 0, r"axes\.X\.compensation\.max_correction_mm: 0"),
    ("axes.X.compensation.pitch", {"file": "x.csv", "interpolation": "cubic"}, r"axes\.X\.compensation\.pitch\.interpolation: 'cubic'"),
    ("axes.X.compensation.thermal", {"source": "nope", "length_mm": 800}, r"axes\.X\.compensation\.thermal\.source: 'nope' is not one of thermal_sources: x_ref"),
    ("axes.X.compensation.thermal", {"source": "x_ref", "length_mm": 0}, r"axes\.X\.compensation\.thermal\.length_mm: 0 must be > 0"),
    ("buses.line1.timeout_s", 0, r"buses\.line1\.timeout_s: 0"),
    ("buses.line1.retries", 9, r"buses\.line1\.retries: 9 is not in 0\.\.5"),
    ("buses.line1.rtu", {"port": "/dev/ttyS0"}, r"buses\.line1: .*exactly one of rtu or tcp"),
    ("buses.line1.tcp.port", 70000, r"buses\.line1\.tcp\.port: 70000 is not in 0\.\.65535"),
    ("buses.line1.tcp", {"host": "127.0.0.1", "port": 1, "tls": True}, r"buses\.line1\.tcp\.tls: unknown key"),
    ("upstream.tcp.allow", ["127.0.0.0/33"], r"upstream\.tcp\.allow: .*not an IP network"),
    ("upstream.tcp", None, r"upstream: .*needs tcp, tls, rtu or any of them together"),
    ("upstream.rtu", {"port": "/dev/ttyS1", "parity": "X"}, r"upstream\.rtu\.parity: 'X'"),
    ("upstream.rtu", {"port": "/dev/ttyS1", "stopbits": 3}, r"upstream\.rtu\.stopbits: 3"),
    ("thermal_sources.x_ref.bus", "line2", r"thermal_sources\.x_ref\.bus: 'line2' is not one of buses"),
    ("thermal_sources.x_ref.register.words", 4, r"thermal_sources\.x_ref\.register\.words: 4"),
    ("status.upstream_unit", 1, r"axes\.X: 1 upstream unit already used by status\.upstream_unit"),
    ("status.remote_control", "maybe", r"status\.remote_control: 'maybe'"),
    ("planar", {"axes": ["X", "Z"], "model": "xy.yaml"}, r"planar\.axes\.1: 'Z' is not one of axes: X, Y"),
    ("planar", {"axes": ["X", "Y"], "model": "xy.yaml", "commit": "later"}, r"planar\.commit: 'later'"),
    ("passthrough", {30: {"bus": "line7", "unit": 5}}, r"passthrough\.30\.bus: 'line7' is not one of buses"),
    ("colour", "blue", r"colour: unknown key"),
    ("axes.X.command_scale", 10, r"axes\.X: .*command_scale 10 needs registers\.feedback\.upstream_counts_per_pulse"),
    ("axes.X.command_scale", 0, r"axes\.X\.command_scale: 0 is not in 1\.\.1000"),
    ("axes.X.pulse_mm", 0.0000001, r"axes\.X: .*travel_mm 800 is 8e\+09 drive units .*signed 32-bit"),
]


def test_base_config_is_valid():
    config = parse_config(copy.deepcopy(BASE))
    assert config.axes["X"].upstream == 1
    assert config.axes["X"].registers.trigger.value == 0x10


@pytest.mark.parametrize(("path", "value", "message"), BAD, ids=[b[0] + "=" + repr(b[1])[:20] for b in BAD])
def test_bad_config_names_the_field(path, value, message):
    with pytest.raises(ConfigError, match=message) as info:
        parse_config(with_change(path, value), source="gw.yaml")
    text = str(info.value)
    assert text.startswith("gw.yaml: ")
    assert "\n" not in text


def test_bad_yaml_and_missing_file(tmp_path: Path):
    path = tmp_path / "gw.yaml"
    path.write_text("upstream:\n  tcp: {host: 127.0.0.1\n")
    with pytest.raises(ConfigError, match=r"gw\.yaml: line \d+: not valid YAML"):
        load_config(path)
    with pytest.raises(ConfigError, match="file not found"):
        load_config(tmp_path / "nope.yaml")
    path.write_text("- a list\n")
    with pytest.raises(ConfigError, match="top level must be a mapping"):
        load_config(path)
    path.write_text(yaml.safe_dump(BASE))
    assert load_config(path).buses["line1"].timeout_s == 0.1


def test_a_key_given_twice_is_refused_naming_it_and_both_lines(tmp_path: Path):
    """YAML forbids it; PyYAML would keep the last silently (a second ``X:`` axis replaced
    the first, a second ``travel_mm`` the first), in block and flow style alike."""
    path = tmp_path / "gw.yaml"
    text = yaml.safe_dump(BASE, sort_keys=False)
    lines = text.splitlines()
    at = next(i for i, ln in enumerate(lines) if ln.strip().startswith("travel_mm"))
    lines.insert(at + 1, lines[at])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ConfigError, match=rf"gw\.yaml: line {at + 2}: not valid YAML \(key "
                                          rf"'travel_mm' given twice \(first on line {at + 1}\)"):
        load_config(path)
    path.write_text(text + "status: {a: 1, a: 2}\n")  # (the top level's status again, too)
    with pytest.raises(ConfigError, match="given twice"):
        load_config(path)


@pytest.mark.parametrize(
    ("source", "message"),
    [
        ({"range_mm": [0.5, -0.5]}, r"thermal_sources\.x_ref\.range_mm: .*low < high"),
        ({"kind": "temperature", "alpha_per_k": 0}, r"thermal_sources\.x_ref: .*alpha_per_k > 0"),
        ({"scale_mm": 0}, r"thermal_sources\.x_ref: .*scale_mm must not be 0"),
        ({"noise_mm": -1}, r"thermal_sources\.x_ref\.noise_mm: -1"),
    ],
)
def test_bad_thermal_source(source, message):
    data = copy.deepcopy(BASE)
    data["thermal_sources"]["x_ref"].update(source)
    with pytest.raises(ConfigError, match=message):
        parse_config(data)


@pytest.mark.parametrize(("path", "value", "message"), BAD, ids=[b[0] + "=" + repr(b[1])[:20] for b in BAD])
def test_check_exits_1_naming_the_field(tmp_path: Path, capsys, path, value, message):
    """The same table through `compgw check`: exit code 1 and one line on stderr."""
    from gateway.cli import main

    config = tmp_path / "gw.yaml"
    config.write_text(yaml.safe_dump(with_change(path, value)))
    assert main(["check", "-c", str(config)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert re.search(message, err), err


def test_check_warns_when_corrections_are_rounded_to_coarse_drive_units():
    data = copy.deepcopy(BASE)  # 1 µm pulses, backlash compensation on X
    found = [w for w in warnings(parse_config(copy.deepcopy(data))) if "drive units" in w]
    assert found == ["axes.X: corrections land to whole drive units of 1 µm (up to ±0.5 µm of "
                     'rounding); gear the drive finer and set command_scale (docs/retrofit.md, '
                     '"Resolution first")']  # fmt: skip
    data["axes"]["X"]["command_scale"] = 10
    data["axes"]["X"]["registers"]["feedback"]["upstream_counts_per_pulse"] = 1
    assert not [w for w in warnings(parse_config(copy.deepcopy(data))) if "drive units" in w]
    data = copy.deepcopy(BASE)
    data["axes"]["X"]["compensation"] = {}  # nothing corrected: nothing to round
    assert not [w for w in warnings(parse_config(data)) if "drive units" in w]


def test_check_warns_of_a_plain_port_open_beside_tls():
    """The README's rule: with upstream.tls, upstream.tcp off or on loopback."""
    data = copy.deepcopy(BASE)
    data["upstream"]["tls"] = {"port": 802, "cert": "s.pem", "key": "s.key", "ca": "ca.pem"}
    for host in ("127.0.0.1", "::1", "localhost"):
        data["upstream"]["tcp"]["host"] = host
        assert not [w for w in warnings(parse_config(copy.deepcopy(data))) if "tls" in w]
    data["upstream"]["tcp"] = {"host": "0.0.0.0", "port": 5020, "allow": ["0.0.0.0/0"]}
    found = [w for w in warnings(parse_config(copy.deepcopy(data))) if "tls" in w]
    assert len(found) == 1 and found[0].startswith("upstream.tcp: plain Modbus/TCP on "
                                                   "0.0.0.0:5020 beside upstream.tls")  # fmt: skip


@pytest.mark.parametrize(
    ("thermal", "message"),
    [
        ({"length_mm": 800, "source": "x_ref",
          "motion": {"delta_a_um_per_m": 1, "tau_s": 60}}, r"thermal: give either source"),
        ({"length_mm": 800, "motion": {"delta_a_um_per_m": 1, "tau_s": 60,
                                       "speeds_mm_s": {"Q": 100}}},
         r"axes\.X\.compensation\.thermal\.motion\.speeds_mm_s\.Q: 'Q' is not one of axes"),
        ({"length_mm": 800, "motion": {"delta_a_um_per_m": 1, "tau_s": 0}},
         r"thermal\.motion\.tau_s"),
    ],
)
def test_bad_heat_from_motion_names_the_field(thermal, message):
    data = copy.deepcopy(BASE)
    data["axes"]["X"].setdefault("compensation", {})["thermal"] = thermal
    with pytest.raises(ConfigError, match=message):
        parse_config(data)


def test_a_missing_table_file_is_named_by_its_key(tmp_path: Path):
    """Every config error names the YAML path: a missing table too, not only its file."""
    from gateway.tables import build_chain

    data = copy.deepcopy(BASE)
    data["axes"]["X"]["compensation"] = {"pitch": {"file": "x.csv"}}
    with pytest.raises(ConfigError, match=r"^axes\.X\.compensation\.pitch\.file: .*x\.csv: "
                                          r"file not found$"):  # fmt: skip
        build_chain(parse_config(copy.deepcopy(data)), tmp_path)
    (tmp_path / "x.csv").write_text("position_mm,forward_um\n0,1\n800,2\n")
    build_chain(parse_config(copy.deepcopy(data)), tmp_path)  # there now: it loads
    data["axes"]["X"]["compensation"]["cyclic"] = "x_cyclic.yaml"
    with pytest.raises(ConfigError, match=r"^axes\.X\.compensation\.cyclic: .*x_cyclic\.yaml: "
                                          r"file not found$"):  # fmt: skip
        build_chain(parse_config(copy.deepcopy(data)), tmp_path)


def test_a_required_key_misspelt_is_said_beside_its_absence():
    data = copy.deepcopy(BASE)
    data["axes"]["X"]["travel_mmm"] = data["axes"]["X"].pop("travel_mm")
    with pytest.raises(ConfigError) as info:
        parse_config(data, source="gw.yaml")
    assert str(info.value) == ("gw.yaml: axes.X.travel_mm: missing (required); 'travel_mmm' "
                               "beside it is no key (a typo?)")  # fmt: skip


def test_check_warns_of_heat_from_motion_without_a_state_file():
    """Trial 8: restarted without one, a warm machine read 13 µm where it had read 2.7."""
    data = copy.deepcopy(BASE)
    data["axes"]["X"]["compensation"]["thermal"] = {
        "motion": {"delta_a_um_per_m": 1.0, "tau_s": 600, "speeds_mm_s": {"X": 100}},
        "length_mm": 800}
    found = [w for w in warnings(parse_config(copy.deepcopy(data))) if "state_file" in w]
    assert len(found) == 1 and found[0].startswith(
        "axes.X.compensation.thermal.motion without a state_file: a restart")
    data["state_file"] = "run/state.json"
    assert not [w for w in warnings(parse_config(data)) if "state_file" in w]
