"""Config loading: shipped configs load; every error names the file and the key."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.rigs import unique_addresses, write_config
from tmscal.config import load_config
from tmscal.errors import ConfigError
from tmscal.mocks.launch import build_sim_rig
from tmscal.sim import TMS_RIG_P0, tms_rig_truth

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.mark.parametrize("name", ["mock-ur-polaris.yaml", "mock-denso-polaris.yaml",
                                  "mock-polaris.yaml", "mock-ur.yaml", "mock-denso.yaml",
                                  "mock-ur-polaris-realtime.yaml",
                                  "mock-franka-polaris.yaml", "mock-ur-ati.yaml",
                                  "mock-ur-igtl.yaml", "mock-ur-polaris-kin.yaml",
                                  "mock-denso-polaris-kin.yaml"])
def test_shipped_mock_configs_load(name):
    cfg = load_config(CONFIGS / name)
    assert cfg.mock is not None
    rig = build_sim_rig(cfg)
    np.testing.assert_array_equal(rig.truth.Y, tms_rig_truth().Y)
    np.testing.assert_array_equal(rig.commanded, TMS_RIG_P0)


@pytest.mark.parametrize("name", ["ur-polaris.yaml", "denso-polaris.yaml",
                                  "franka-polaris.yaml"])
def test_templates_name_the_rom_to_fix(name):
    with pytest.raises(ConfigError, match=r"key 'tracker.tools.marker': ROM file not found"):
        load_config(CONFIGS / name)


def test_igtl_template_loads_and_marks_what_to_check():
    """The OpenIGTLink template needs no file to load; its source address, transform names
    and frame rate are marked CHECK, and it builds the driver it names (not opened)."""
    from tmscal.acquisition.devices import make_tracker

    path = CONFIGS / "ur-igtl.yaml"
    cfg = load_config(path)
    assert cfg.tracker.driver == "igtl" and set(cfg.tracker.tools) == {"marker", "probe"}
    tracker_lines = path.read_text().split("\ntracker:\n")[1].split("\nplan:")[0]
    for key in ("host:", "port:", "frame_rate_hz:", "marker:", "probe:"):
        line = next(ln for ln in tracker_lines.splitlines() if ln.strip().startswith(key))
        assert "CHECK" in line, line
    t = make_tracker(cfg)
    s = cfg.tracker.settings
    assert (t.host, t.port, t.device_names) == (s.host, s.port, s.tools)


#: a complete safety section (a config that drives a robot must set every limit)
SAFE = {"max_offset_mm": 200, "max_rotation_deg": 20, "workspace_min_mm": [100, -400, 0],
        "workspace_max_mm": [900, 400, 800], "max_speed_mm_s": 250, "max_accel_mm_s2": 1500,
        "tool_points_mm": [[0, 0, 100]]}


def _write(tmp_path, data):
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return p


@pytest.mark.parametrize("data, key", [
    ({"robot": {"driver": "kuka"}}, "robot.driver"),
    ({"robot": {"driver": "ur", "speed_mm_s": "fast"}}, "robot.speed_mm_s"),
    ({"robot": {"driver": "ur", "speed_mm_s": 900}, "safety": SAFE}, "robot.speed_mm_s"),
    ({"robot": {"driver": "ur", "sped": 1}}, "robot.sped"),
    ({"plan": {"kind": "grid"}}, "plan.kind"),
    ({"plan": {"poses": 0}}, "plan.poses"),
    ({"plan": {"start": [[1, 0], [0, 1]]}}, "plan.start"),
    ({"sampling": {"min_share": 1.5}}, "sampling.min_share"),
    ({"safety": {"workspace_min_mm": [0, 0, 0]}}, "safety.workspace_min_mm"),
    ({"safety": {"workspace_min_mm": [0, 0], "workspace_max_mm": [1, 1, 1]}},
     "safety.workspace_min_mm"),
    ({"mock": {"clock": "slow"}}, "mock.clock"),
    ({"trackr": {}}, "trackr"),
])
def test_errors_name_file_and_key(tmp_path, data, key):
    p = _write(tmp_path, data)
    with pytest.raises(ConfigError) as e:
        load_config(p)
    assert str(p) in str(e.value) and f"key '{key}'" in str(e.value)


def test_bad_yaml_names_line(tmp_path):
    p = _write(tmp_path, "robot:\n  driver: ur\n   host: x\n")
    with pytest.raises(ConfigError, match=r"c.yaml, line \d+: invalid YAML"):
        load_config(p)


def test_missing_file():
    with pytest.raises(ConfigError, match="cannot read config"):
        load_config("/nonexistent/rig.yaml")


def test_rom_paths_resolve_against_config_folder(tmp_path):
    (tmp_path / "t").mkdir()
    (tmp_path / "t" / "m.rom").write_bytes(b"NDI")
    p = _write(tmp_path, {"tracker": {"port": "/dev/null", "tools": {"marker": "t/m.rom"}}})
    assert load_config(p).tracker.tools["marker"] == str(tmp_path / "t" / "m.rom")


def test_start_pose_from_xyz_rpy(tmp_path):
    p = _write(tmp_path, {"plan": {"start": {"xyz_mm": [500, 0, 400], "rpy_deg": [180, 0, 0]}}})
    np.testing.assert_allclose(load_config(p).plan.start, TMS_RIG_P0, atol=1e-12)


def test_unknown_driver_and_fault_options_are_named(tmp_path):
    from tmscal.mocks.launch import start_mock_rig
    data = unique_addresses(yaml.safe_load((CONFIGS / "mock-denso-polaris.yaml").read_text()))
    data["tracker"]["tools"] = {k: str(CONFIGS / v) for k, v in data["tracker"]["tools"].items()}
    data["robot"]["options"] = {"max_linear_speed_mm_s": 1000, "turbo": True}
    data["mock"]["tracker"] = {"faults": {"crc_eror_prob": 0.1}}
    p = _write(tmp_path, data)
    # the driver's settings declare its options: an unknown one is refused at load
    with pytest.raises(ConfigError, match=r"key 'robot.options': unknown key 'turbo'.*"
                                          r"max_linear_speed_mm_s"):
        load_config(p)
    del data["robot"]["options"]["turbo"]
    cfg = load_config(_write(tmp_path, data))
    with pytest.raises(ConfigError, match=r"key 'mock.tracker.faults': unknown key "
                                          r"'crc_eror_prob'.*crc_error_prob"):
        start_mock_rig(cfg)


def _rom_path(tmp_path, case):
    """A ROM path the file system refuses: a name over 255 characters, a path over 4096, a
    symbolic link loop, a directory."""
    if case == "loop":
        (tmp_path / "loop").symlink_to("loop")
    return {"name over 255": str(tmp_path / ("m" * 300 + ".rom")),
            "path over 4096": "/tmp/" + "d/" * 2100 + "m.rom",
            "loop": str(tmp_path / "loop"), "directory": str(tmp_path)}[case]


@pytest.mark.parametrize("case, problem", [
    ("name over 255", "ENAMETOOLONG"), ("path over 4096", "ENAMETOOLONG"),
    ("loop", "ELOOP"), ("directory", "not a regular file")])
def test_a_rom_path_the_file_system_refuses_is_a_config_error(tmp_path, case, problem):
    """Issue 22, #10: a ROM path over 255 characters gave a raw OSError. Every file system
    refusal is a ConfigError naming the file, the line and the tool's key, with the errno's
    name, in one line of bounded length (the path shortened), at load and when a config
    loaded without the file check builds the tracker."""
    from tmscal.acquisition.devices import make_tracker

    rom = _rom_path(tmp_path, case)
    p = _write(tmp_path, {"tracker": {"port": "/dev/null", "tools": {"marker": rom}}})
    with pytest.raises(ConfigError) as e:
        load_config(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}, line 4: key 'tracker.tools.marker': ROM file ")
    assert problem in msg and "\n" not in msg and len(msg) < len(str(p)) + 220
    cfg = load_config(p, check_files=False)
    with pytest.raises(ConfigError, match=r"key 'tracker.tools.marker': ROM file .*"
                                          + problem):
        make_tracker(cfg)


def test_a_wire_log_path_the_file_system_refuses_is_a_config_error(tmp_path):
    """``tracker.log_wire`` over 255 characters, beside a ROM path in a symbolic link loop:
    a ConfigError naming log_wire, not a raw OSError or RuntimeError."""
    (tmp_path / "loop").symlink_to("loop")
    data = {"tracker": {"port": "/dev/ttyUSB0", "tools": {"marker": str(tmp_path / "loop")},
                        "log_wire": str(tmp_path / ("w" * 300 + ".log"))}}
    with pytest.raises(ConfigError, match=r"key 'tracker.log_wire': .*ENAMETOOLONG"):
        load_config(_write(tmp_path, data), check_files=False)
    data["tracker"]["log_wire"] = str(tmp_path / "w.log")
    cfg = load_config(_write(tmp_path, data), check_files=False)
    assert cfg.tracker.settings.log_wire == str(tmp_path / "w.log")


@pytest.mark.parametrize("n", [1, 2])
def test_a_plan_of_fewer_than_three_poses_is_refused(tmp_path, n):
    """A solve needs at least 3 poses, so a config's plan.poses below 3 is refused, naming the
    key, as `acquire --poses` is (issue 24 item 6)."""
    cfg = write_config(tmp_path, "mock-denso-polaris.yaml", plan={"poses": n})
    with pytest.raises(ConfigError, match=r"key 'plan\.poses': must be at least 3"):
        load_config(cfg)
