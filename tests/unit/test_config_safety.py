"""Hostile configs: every one is a ConfigError naming the file and the key (and the line, for a
file), raised at load, before any device is built or opened."""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from tmscal import registry
from tmscal.acquisition.devices import envelope_for, make_robot, make_tracker
from tmscal.acquisition.plan import plan_summary
from tmscal.config import SAFETY_KEYS, load_config, parse_config
from tmscal.drivers.base import Envelope
from tmscal.drivers.ndi.settings import tracker_port_problem
from tmscal.drivers.sim.robot import SimRobot
from tmscal.errors import ConfigError, SafetyError

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
ROM = str(CONFIGS / "tools" / "marker-8700340.rom")

SAFE = {"max_offset_mm": 200, "max_rotation_deg": 20, "workspace_min_mm": [100, -400, 0],
        "workspace_max_mm": [900, 400, 800], "max_speed_mm_s": 250, "max_accel_mm_s2": 1500,
        "tool_points_mm": [[3, 5, 110]]}
ROBOT = {"driver": "ur", "host": "127.0.0.2", "speed_mm_s": 100, "accel_mm_s2": 500}


def rig(**changes):
    data = {"robot": dict(ROBOT), "safety": dict(SAFE)}
    for k, v in changes.items():
        if v is None:
            data.pop(k, None)
        else:
            data[k] = v
    return data


def key_error(data, key):
    with pytest.raises(ConfigError) as e:
        parse_config(data, "rig.yaml")
    msg = str(e.value)
    assert msg.startswith("rig.yaml") and f"key '{key}" in msg, msg  # or a part of it
    assert "\n" not in msg
    return msg


# --- a robot needs a complete safety section ------------------------------------------------

def test_robot_without_safety_section_is_refused():
    msg = key_error(rig(safety=None), "safety")
    assert msg == ("rig.yaml: key 'safety': a config that drives a robot needs a safety "
                   "section (max_offset_mm, max_rotation_deg, workspace_min_mm, "
                   "workspace_max_mm, max_speed_mm_s, max_accel_mm_s2)")


@pytest.mark.parametrize("key", SAFETY_KEYS)
def test_robot_needs_every_safety_limit(key):
    s = dict(SAFE)
    del s[key]
    key_error(rig(safety=s), f"safety.{key}")
    s[key] = None
    key_error(rig(safety=s), f"safety.{key}")


def test_no_robot_no_safety_needed():
    cfg = parse_config({"plan": {"poses": 3}}, "rig.yaml")
    assert cfg.robot is None and cfg.safety.max_offset_mm > 0


def test_missing_tool_points_warns(caplog):
    s = dict(SAFE)
    del s["tool_points_mm"]
    with caplog.at_level(logging.WARNING, logger="tmscal.config"):
        parse_config(rig(safety=s), "rig.yaml")
    assert any("tool_points_mm" in r.getMessage() and "FLANGE only" in r.getMessage()
               for r in caplog.records)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="tmscal.config"):
        parse_config(rig(), "rig.yaml")
    assert not caplog.records


BAD_NUMBERS = [math.nan, math.inf, -math.inf, True, "200", 10**400, 10**30, -1, 0, -0.0,
               None, [1]]


@pytest.mark.parametrize("key", ["max_offset_mm", "max_rotation_deg", "max_speed_mm_s",
                                 "max_accel_mm_s2"])
@pytest.mark.parametrize("value", BAD_NUMBERS, ids=repr)
def test_safety_limit_values(key, value):
    key_error(rig(safety={**SAFE, key: value}), f"safety.{key}")


@pytest.mark.parametrize("key", ["workspace_min_mm", "workspace_max_mm"])
@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, True, "1", 10**400, 10**30],
                         ids=repr)
def test_workspace_coordinates(key, axis, value):
    xyz = list(SAFE[key])
    xyz[axis] = value
    key_error(rig(safety={**SAFE, key: xyz}), f"safety.{key}")


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_workspace_min_below_max_per_axis(axis):
    lo, hi = list(SAFE["workspace_min_mm"]), list(SAFE["workspace_max_mm"])
    lo[axis], hi[axis] = hi[axis], lo[axis]        # reordered
    msg = key_error(rig(safety={**SAFE, "workspace_min_mm": lo, "workspace_max_mm": hi}),
                    "safety.workspace_max_mm")
    assert "xyz"[axis] in msg
    hi = list(SAFE["workspace_max_mm"])
    hi[axis] = SAFE["workspace_min_mm"][axis]      # empty on one axis
    key_error(rig(safety={**SAFE, "workspace_max_mm": hi}), "safety.workspace_max_mm")


@pytest.mark.parametrize("points", [[[0, 0, math.nan]], [[0, 0]], [[0, 0, 1e9]], [], "x",
                                    [[0, 0, True]], [[0, 0, 10**400]]], ids=repr)
def test_tool_points(points):
    key_error(rig(safety={**SAFE, "tool_points_mm": points}), "safety.tool_points_mm")


@pytest.mark.parametrize("key, value", [("accel_mm_s2", 0), ("accel_mm_s2", -5),
                                        ("accel_mm_s2", math.nan), ("accel_mm_s2", 1e300),
                                        ("speed_mm_s", 0), ("speed_mm_s", math.inf),
                                        ("accel_mm_s2", 1501), ("speed_mm_s", 251),
                                        ("port", 70000), ("port", -1), ("host", "")])
def test_robot_motion_values(key, value):
    key_error(rig(robot={**ROBOT, key: value}), f"robot.{key}")


def test_negative_zero_rotation_is_zero():
    cfg = parse_config(rig(plan={"rotation_deg": -0.0}), "rig.yaml")
    assert cfg.plan.rotation_deg == 0.0 and math.copysign(1, cfg.plan.rotation_deg) == 1
    key_error(rig(safety={**SAFE, "max_rotation_deg": -0.0}), "safety.max_rotation_deg")


@pytest.mark.parametrize("section, key", [("plan", "seed"), ("mock", "seed")])
def test_negative_seeds(section, key):
    key_error(rig(**{section: {key: -1}}), f"{section}.{key}")


# --- options cannot reach safety arguments ---------------------------------------------------

@pytest.mark.parametrize("key, value", [("envelope", None), ("speed_mm_s", 2000),
                                        ("accel_mm_s2", 1e5), ("host", "10.0.0.1"),
                                        ("port", 1)])
def test_robot_options_cannot_name_safety_arguments(key, value):
    key_error(rig(robot={**ROBOT, "options": {key: value}}), f"robot.options.{key}")


@pytest.mark.parametrize("key", ["port", "tools", "baud", "frame_rate_hz", "reply"])
def test_tracker_options_cannot_name_own_keys(key):
    data = {"tracker": {"port": "/dev/ttyUSB0", "tools": {"marker": ROM},
                        "options": {key: 1}}}
    key_error(data, f"tracker.options.{key}")


#: the in-process sim robot (tmscal/drivers/sim/), a device without a wire, for the checks of
#: make_robot
SIM_ROBOT = {**ROBOT, "driver": "sim"}


def test_make_robot_refuses_options_defensively():
    cfg = parse_config(rig(robot=SIM_ROBOT), "rig.yaml")
    for key, value in (("envelope", None), ("speed_mm_s", 2000), ("accel_mm_s2", 1e5)):
        cfg.robot.options = {key: value}  # as if the parser had been bypassed
        with pytest.raises(ConfigError, match=rf"key 'robot.options.{key}'"):
            make_robot(cfg)


def test_make_robot_always_carries_the_config_envelope():
    cfg = parse_config(rig(robot={**SIM_ROBOT, "options": {"seed": 3}}), "rig.yaml")
    r = make_robot(cfg)
    assert isinstance(r, SimRobot) and r.spec.seed == 3   # the options reach the driver
    assert r.envelope.max_speed_mm_s == 250 and r.envelope.max_accel_mm_s2 == 1500
    assert r.envelope.box_min_mm == (100, -400, 0) and r.envelope.box_max_mm == (900, 400, 800)
    np.testing.assert_array_equal(r.envelope.tool_points_mm, [[3, 5, 110]])
    assert (r.speed_mm_s, r.accel_mm_s2) == (100, 500)
    # on reconnect / resume the rebuilt robot gets the envelope around P0
    env = envelope_for(cfg, np.eye(4))
    assert make_robot(cfg, env).envelope is env
    # an envelope looser than the config is refused
    for loose in (Envelope(), Envelope(max_speed_mm_s=250, max_accel_mm_s2=1500),
                  Envelope(max_speed_mm_s=300, max_accel_mm_s2=1500, box_min_mm=(100, -400, 0),
                           box_max_mm=(900, 400, 800), tool_points_mm=[[3, 5, 110]]),
                  Envelope(max_speed_mm_s=250, max_accel_mm_s2=1500, box_min_mm=(100, -400, 0),
                           box_max_mm=(900, 400, 850), tool_points_mm=[[3, 5, 110]]),
                  Envelope(max_speed_mm_s=250, max_accel_mm_s2=1500, box_min_mm=(100, -400, 0),
                           box_max_mm=(900, 400, 800))):
        with pytest.raises(SafetyError, match="looser"):
            make_robot(cfg, loose)


class Dropper(SimRobot):
    """A broken driver that loses the envelope it was given (no real driver does; the sim
    robot cannot be told to, so this one test keeps a subclass)."""

    def __init__(self, **kw):
        kw["envelope"] = None
        super().__init__(**kw)


def test_make_robot_refuses_a_driver_that_drops_the_envelope(monkeypatch):
    spec = dataclasses.replace(registry.get_spec("sim", "robot"), cls=f"{__name__}:Dropper")
    monkeypatch.setitem(registry.SPECS, registry.slot(spec), spec)
    with pytest.raises(SafetyError, match="did not take"):
        make_robot(parse_config(rig(robot=SIM_ROBOT), "rig.yaml"))


# --- tracker.port: no file-writing URL handlers ----------------------------------------------

@pytest.mark.parametrize("port", ["/dev/ttyUSB0", "/dev/pts/3", "COM3",
                                  "socket://127.0.0.1:8765", "socket://[::1]:8765",
                                  "socket://vega.local:8765", "SOCKET://10.0.0.5:8765",
                                  "/dev/serial/by-path/pci-0000:00:14.0-usb-0:1:1.0-port0",
                                  r"\\.\COM10", "ttyUSB0"])
def test_tracker_ports_accepted(port):
    assert tracker_port_problem(port) is None


@pytest.mark.parametrize("port, url", [
    ("192.168.1.10:8765", "socket://192.168.1.10:8765"),
    ("192.168.1.10", "socket://192.168.1.10:8765"),   # no port: the Vega's API port
    ("vega.local:8765", "socket://vega.local:8765"),
    ("P9-01234:8765", "socket://P9-01234:8765"),
    ("[fe80::1]:8765", "socket://[fe80::1]:8765")])
def test_a_network_address_without_socket_scheme_is_refused_with_the_spelling(port, url):
    """A Vega's address written as host:port passed config loading and failed only when the
    port opened, "No such file or directory": refused at load, naming the key and the
    socket:// spelling to use."""
    msg = key_error({"tracker": {"port": port, "tools": {"marker": ROM}}}, "tracker.port")
    assert f"'{port}'" in msg and "without socket://" in msg and url in msg, msg


@pytest.mark.parametrize("port", ["spy:///dev/ttyUSB0?file=/tmp/x", "SPY://x?file=y",
                                  "loop://", "rfc2217://host:2217", "hwgrep://.*",
                                  "alt:///dev/ttyUSB0?class=PosixPollSerial", "cp2110://1-1",
                                  "socket://host", "socket://h:99999",
                                  "socket://h:1?logging=debug", "socket://h:1/x", "",
                                  "/dev/tty\0x"])
def test_tracker_ports_refused(port, tmp_path):
    assert tracker_port_problem(port) is not None
    if port:
        key_error({"tracker": {"port": port, "tools": {"marker": ROM}}}, "tracker.port")


def test_spy_url_writes_no_file(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    url = f"spy://loop://?file={victim}"
    p = tmp_path / "rig.yaml"
    p.write_text(yaml.safe_dump({"tracker": {"port": url, "tools": {"marker": ROM}}}))
    with pytest.raises(ConfigError, match=r"line 2: key 'tracker.port'"):
        load_config(p)
    # a CLI override goes through the same check
    cfg = parse_config({"tracker": {"port": "/dev/null", "tools": {"marker": ROM}}}, "rig.yaml")
    with pytest.raises(ConfigError, match="key 'tracker.port'"):
        make_tracker(cfg, url)
    # and the driver itself refuses it (defence in depth)
    from tmscal.drivers.ndi.tracker import NDITracker
    with pytest.raises(ConfigError, match="refused"):
        NDITracker(url, {"marker": ROM}).open()
    assert victim.read_text() == "precious"


# --- hostile structures ----------------------------------------------------------------------

@pytest.mark.parametrize("data, key", [
    ({1: "x", "robot": ROBOT}, "1"),
    ({"robot": {**ROBOT, 1: 2}, "safety": SAFE}, "robot.1"),
    ({**rig(), "robot": {**ROBOT, "options": {1: 2, "a": 3}}}, "robot.options.1"),
    ({"tracker": {"port": "/dev/ttyUSB0", "tools": {1: ROM, "a": ROM}}}, "tracker.tools.1"),
    ({"mock": {"tracker": {"faults": "denso"}}}, "mock.tracker.faults"),
    ({"mock": {"robot": {"faults": [1, 2]}}}, "mock.robot.faults"),
    ({"mock": {"noise": {"fiducial_sigma_mm": math.nan}}}, "mock.noise.fiducial_sigma_mm"),
    ({"mock": {"truth": {"X": np.eye(4).tolist(), "Z": np.eye(4).tolist(), "Q": 1}}},
     "mock.truth.Q"),
    ({"plan": {"radius_mm": 10**400}}, "plan.radius_mm"),
    ({"plan": {"poses": 10**400}}, "plan.poses"),
    ({"plan": {"poses": 10**9}}, "plan.poses"),
    ({"plan": {"start": {"xyz_mm": [0, 0, math.nan]}}}, "plan.start.xyz_mm[2]"),
    ({"plan": {"start": "home"}}, "plan.start"),
    ({"name": 3}, "name"),
    ({"description": b"bytes"}, "description"),
    ({"run": {"retries": -1}}, "run.retries"),
])
def test_hostile_structures(data, key):
    key_error(data, key)


def test_recursive_structure_is_refused():
    a: list = []
    a.append(a)
    key_error({**rig(), "robot": {**ROBOT, "options": {"upload_script": a}}},
              "robot.options.upload_script")
    d: dict = {}
    d["x"] = d
    key_error({"mock": {"tracker": d}}, "mock.tracker.x")


def test_deep_nesting_is_refused():
    v: object = 1
    for _ in range(5000):
        v = [v]
    msg = key_error({"mock": {"tracker": {"x": v}}}, "mock.tracker.x" + "[0]" * 30)
    assert "deep" in msg


def _load(tmp_path, text):
    p = tmp_path / "rig.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_config(p)
    msg = str(e.value)
    assert msg.startswith(str(p)) and "\n" not in msg, msg
    return msg


def test_yaml_hostile_documents(tmp_path):
    # a YAML anchor cycle: safe_load builds a recursive list
    msg = _load(tmp_path, "name: x\nrobot:\n  driver: ur\n  options: {upload_script: &x [*x]}\n")
    assert "line 4: key 'robot.options.upload_script" in msg
    assert "refers to itself" in msg
    # deep nesting (the YAML parser itself recurses)
    _load(tmp_path, "mock: {tracker: {x: " + "[" * 20000 + "]" * 20000 + "}}\n")
    # an integer too long to print, a float that overflows
    _load(tmp_path, "plan: {radius_mm: 1" + "0" * 6000 + "}\n")
    assert "plan.radius_mm" in _load(tmp_path, "plan: {radius_mm: 1e400}\n")
    # aliases expanded a billion times
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    text = "mock:\n  tracker:\n" + "".join(f"    {ln}\n" for ln in lines)
    assert "more than" in _load(tmp_path, text)
    # mixed key types, a date, a set
    assert "line 2: key '1'" in _load(tmp_path, "plan: {poses: 3}\n1: x\n")
    assert "key 'description'" in _load(tmp_path, "description: 2024-01-01\n")
    assert "key 'mock.robot.x'" in _load(tmp_path, "mock: {robot: {x: !!set {a, b}}}\n")


def test_too_large_file(tmp_path):
    assert "larger than" in _load(tmp_path, "# " + "x" * 1_000_001 + "\n")


def test_errors_carry_the_line(tmp_path):
    data = yaml.safe_load((CONFIGS / "mock-ur.yaml").read_text())
    text = (CONFIGS / "mock-ur.yaml").read_text().replace("max_rotation_deg: 20",
                                                          "max_rotation_deg: .nan")
    line = 1 + text.splitlines().index("  max_rotation_deg: .nan")
    msg = _load(tmp_path, text)
    assert f"rig.yaml, line {line}: key 'safety.max_rotation_deg'" in msg
    assert data["safety"]["max_rotation_deg"] == 20


def test_shipped_robot_configs_have_tool_points():
    for name in ("mock-ur-polaris", "mock-denso-polaris", "mock-ur", "mock-denso",
                 "ur-polaris", "denso-polaris", "mock-franka-polaris", "franka-polaris",
                 "mock-ur-polaris-realtime", "mock-ur-ati", "mock-ur-polaris-kin",
                 "mock-denso-polaris-kin"):
        data = yaml.safe_load((CONFIGS / f"{name}.yaml").read_text())
        for k in (*SAFETY_KEYS, "tool_points_mm"):
            assert data["safety"].get(k) is not None, (name, k)


def test_raw_config_is_plain_json():
    import json
    cfg = parse_config(copy.deepcopy(rig()), "rig.yaml")
    assert json.loads(json.dumps(cfg.raw, allow_nan=False)) == cfg.raw


# --- the dry run's extents -------------------------------------------------------------------

def test_plan_summary_box_flange_and_tool_extents():
    R = np.diag([1.0, -1.0, -1.0])  # flange z down
    poses = np.stack([np.eye(4)] * 2)
    poses[:, :3, :3] = R
    poses[0, :3, 3] = [500, 0, 400]
    poses[1, :3, 3] = [600, -50, 300]
    env = Envelope(box_min_mm=(100, -400, 0), box_max_mm=(900, 400, 800),
                   tool_points_mm=[[0, 0, 100], [60, 0, 100]])
    s = plan_summary(poses, poses[0], 100.0, 0.0, 10, 60.0, envelope=env)
    assert s["box_min_mm"] == [100, -400, 0] and s["box_max_mm"] == [900, 400, 800]
    assert s["flange_min_mm"] == [500, -50, 300] and s["flange_max_mm"] == [600, 0, 400]
    # tool points: (500,0,300), (560,0,300), (600,-50,200), (660,-50,200)
    assert s["tool_min_mm"] == [500, -50, 200] and s["tool_max_mm"] == [660, 0, 300]
    s = plan_summary(poses, poses[0], 100.0, 0.0, 10, 60.0)
    assert s["box_min_mm"] is None and s["tool_min_mm"] is None
    assert s["flange_max_mm"] == [600, 0, 400] and s["poses"] == 2


# --- units sanity: values written in metres (issue 22, "Units sanity") ---------------------

#: a robot config's sections written in metres by mistake, the key named, the cause said
METRES = {
    "tool points": ({"safety": {"tool_points_mm": [[0.003, 0.005, 0.11], [0.063, 0.005, 0.11],
                                                   [-0.057, 0.005, 0.11]]}},
                    "safety.tool_points_mm", "these look like metres"),
    "box": ({"safety": {"workspace_min_mm": [0.1, -0.4, 0], "workspace_max_mm": [0.9, 0.4, 0.8]}},
            "safety.workspace_min_mm", "these look like metres"),
    "speed": ({"robot": {"speed_mm_s": 0.05}}, "robot.speed_mm_s", "this looks like m/s;"),
    "accel": ({"robot": {"accel_mm_s2": 0.5}}, "robot.accel_mm_s2", "this looks like m/s²"),
    "max speed": ({"robot": {"speed_mm_s": 0.1}, "safety": {"max_speed_mm_s": 0.25}},
                  "safety.max_speed_mm_s", "this looks like m/s;"),
    "max accel": ({"robot": {"accel_mm_s2": 0.5}, "safety": {"max_accel_mm_s2": 0.9}},
                  "safety.max_accel_mm_s2", "this looks like m/s²"),
}


def _dry_run_config(tmp_path, changes):
    """configs/mock-ur-polaris.yaml with P0 given (the dry run asks no robot) and sections
    updated by ``changes``, written as rig.yaml in ``tmp_path``."""
    data = yaml.safe_load((CONFIGS / "mock-ur-polaris.yaml").read_text())
    data["tracker"]["tools"] = {k: str(CONFIGS / v) for k, v in data["tracker"]["tools"].items()}
    data["plan"]["start"] = {"xyz_mm": [500, 0, 400], "rpy_deg": [180, 0, 0]}
    for section, values in changes.items():
        data[section].update(values)
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(data))
    return "rig.yaml"


@pytest.mark.parametrize("case", list(METRES))
def test_values_in_metres_are_refused_in_one_short_line(tmp_path, monkeypatch, case):
    """Tool points in metres passed every check (the box then bounded the flange only: the
    dry run said "every pose inside"), a box in metres was refused in a 1,000-character line
    without a word about units, a speed of 0.05 (m/s) was accepted. Each is refused by
    ``tmscal acquire --dry-run`` in one line under 200 characters naming the key and the
    likely cause; the same config in mm runs its dry run."""
    from click.testing import CliRunner

    from tmscal.cli import main

    monkeypatch.chdir(tmp_path)
    ok = CliRunner().invoke(main, ["acquire", _dry_run_config(tmp_path, {}), "-o", "s.jsonl",
                                   "--dry-run"])
    assert ok.exit_code == 0 and "inside" in ok.stdout, ok.output
    changes, key, cause = METRES[case]
    r = CliRunner().invoke(main, ["acquire", _dry_run_config(tmp_path, changes), "-o",
                                  "s.jsonl", "--dry-run"])
    assert r.exit_code == 1, r.output
    line = r.stderr
    assert line.startswith("error: rig.yaml, line ") and line.count("\n") == 1, line
    assert f"key '{key}'" in line and cause in line and len(line) < 200, (len(line), line)
    assert not (tmp_path / "s.jsonl").exists()


@pytest.mark.parametrize("points", [[[0, 0, 5]], [[4.9, 0, 0], [0, 0, 120]], [[-5, 0, 0]]])
def test_tool_points_beyond_a_few_mm_are_millimetres(points):
    """Only points that ALL lie within 5 mm of the flange on every axis look like metres: a
    point 5 mm out, or one real coil point among them, is mm."""
    cfg = parse_config(rig(safety={**SAFE, "tool_points_mm": points}), "rig.yaml")
    assert cfg.safety.tool_points_mm is not None


@pytest.mark.parametrize("lo, hi, metres", [
    ([0.1, -0.4, 0], [0.9, 0.4, 0.8], True), ([-9.9, -9.9, -9.9], [9.9, 9.9, 9.9], True),
    ([0.1, -0.4, 0], [0.9, 0.4, 10], False), ([-10, -1, -1], [1, 1, 1], False)])
def test_a_box_below_ten_on_every_coordinate_is_metres(lo, hi, metres):
    data = rig(safety={**SAFE, "workspace_min_mm": lo, "workspace_max_mm": hi})
    if metres:
        msg = key_error(data, "safety.workspace_min_mm")
        assert "these look like metres" in msg and "m = [" in msg
    else:
        assert parse_config(data, "rig.yaml").safety.workspace_min_mm == tuple(lo)


@pytest.mark.parametrize("section, key, value", [
    ("robot", "speed_mm_s", 0.999), ("robot", "accel_mm_s2", 0.5),
    ("safety", "max_speed_mm_s", 0.5), ("safety", "max_accel_mm_s2", 0.05)])
def test_speeds_and_accelerations_below_one_are_si(section, key, value):
    """Below 1 mm/s (mm/s²) is refused naming the value in mm; exactly 1 is accepted."""
    base = {"robot": ROBOT, "safety": SAFE}[section]
    msg = key_error(rig(**{section: {**base, key: value}}), f"{section}.{key}")
    assert f"= {value * 1000:g} mm/s" in msg and "this looks like m/s" in msg
    one = {"robot": {**ROBOT, "speed_mm_s": 1, "accel_mm_s2": 1},
           "safety": {**SAFE, "max_speed_mm_s": 1, "max_accel_mm_s2": 1}}
    cfg = parse_config(rig(**one), "rig.yaml")
    assert (cfg.robot.speed_mm_s, cfg.safety.max_accel_mm_s2) == (1, 1)
