"""Each driver owns its config: its settings class declares its keys and options, a tracker
driver registered with one line loads through ``load_config`` (no config module knows it),
and every error names the file, the line and the key, the driver's own keys included."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import pytest

from tmscal import registry
from tmscal.acquisition.devices import make_ft, make_robot, make_tracker
from tmscal.config import Option, TrackerSettings, load_config, parse_config
from tmscal.config.values import err, in_range, show
from tmscal.drivers.base import Tracker
from tmscal.errors import ConfigError

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
ROM = str(CONFIGS / "tools" / "marker-8700340.rom")
SAFE = {"max_offset_mm": 200, "max_rotation_deg": 20, "workspace_min_mm": [100, -400, 0],
        "workspace_max_mm": [900, 400, 800], "max_speed_mm_s": 250, "max_accel_mm_s2": 1500,
        "tool_points_mm": [[0, 0, 100]]}


# --- a tracker driver from outside the config package --------------------------------------

@dataclass(frozen=True)
class LabSettings(TrackerSettings):
    """A networked tracker that knows each tool by a device name: ``host``, ``port``."""

    KEYS: ClassVar[tuple[str, ...]] = ("host", "port")
    ADDRESS_KEY: ClassVar[str] = "host"
    OPTIONS: ClassVar[Mapping[str, Option]] = {"timeout_s": Option(float, above=0, hi=60)}

    host: str = ""
    port: int = 18944

    @classmethod
    def parse(cls, section: Mapping[str, Any], src: str, base_dir: Path | None,
              check_files: bool) -> LabSettings:
        s = super().parse(section, src, base_dir, check_files)
        if not s.host:
            raise err(src, "tracker.host", "must not be empty")
        in_range(src, "tracker.port", s.port, 1, 65535)
        return s

    @classmethod
    def parse_tool(cls, name: str, value: Any, src: str, base_dir: Path | None,
                   check_files: bool) -> str:
        if not isinstance(value, str) or not value:
            raise err(src, f"tracker.tools.{name}", f"expected a device name, got {show(value)}")
        return value

    def address(self) -> str:
        return f"{self.host}:{self.port}"

    def with_address(self, text: str) -> LabSettings:
        host, _, port = text.rpartition(":")
        if not host or not port.isdigit() or not 1 <= int(port) <= 65535:
            raise self.err("host", f"{text!r}: expected host:port")
        return dataclasses.replace(self, host=host, port=int(port))


class LabTracker(Tracker):
    """Records what it was built with; never opened here."""

    name = "lab"

    def __init__(self, tools: Mapping[str, str], frame_rate_hz: float, host: str, port: int,
                 timeout_s: float = 1.0) -> None:
        super().__init__(list(tools), frame_rate_hz)
        self.device_names = dict(tools)
        self.host, self.port, self.timeout_s = host, port, timeout_s

    def _open(self) -> None:
        raise AssertionError("not opened in these tests")

    def _close(self) -> None:
        pass

    def _read(self) -> Any:
        raise AssertionError("not read in these tests")


@pytest.fixture
def lab(monkeypatch: pytest.MonkeyPatch) -> None:
    """The one registry line that adds the driver (for one test)."""
    spec = registry.DriverSpec("lab", "tracker", f"{__name__}:LabTracker",
                               settings=f"{__name__}:LabSettings")
    monkeypatch.setitem(registry.SPECS, "lab", spec)


LAB_YAML = """\
name: a lab tracker
tracker:
  driver: lab
  host: 127.0.0.1
  port: {port}
  frame_rate_hz: 30
  options: {options}
  tools:
    marker: {marker}
    probe: ProbeToTracker
"""


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "c.yaml"
    p.write_text(text)
    return p


def _lab(tmp_path: Path, port: Any = 18944, options: str = "{timeout_s: 0.5}",
         marker: str = "MarkerToTracker") -> Path:
    return _write(tmp_path, LAB_YAML.format(port=port, options=options, marker=marker))


def test_a_registered_tracker_driver_loads_and_builds(lab: None, tmp_path: Path) -> None:
    cfg = load_config(_lab(tmp_path))
    assert cfg.tracker is not None and isinstance(cfg.tracker.settings, LabSettings)
    assert (cfg.tracker.settings.host, cfg.tracker.settings.port) == ("127.0.0.1", 18944)
    assert cfg.tracker.tools == {"marker": "MarkerToTracker", "probe": "ProbeToTracker"}
    assert cfg.bodies == ["marker", "probe"]
    tr = make_tracker(cfg)
    assert isinstance(tr, LabTracker) and not tr.is_open
    assert tr.device_names == {"marker": "MarkerToTracker", "probe": "ProbeToTracker"}
    assert (tr.host, tr.port, tr.timeout_s, tr.frame_rate_hz) == ("127.0.0.1", 18944, 0.5, 30)
    # the command line's address override goes through the driver's with_address
    moved = make_tracker(cfg, "127.0.0.5:2000")
    assert isinstance(moved, LabTracker) and (moved.host, moved.port) == ("127.0.0.5", 2000)
    with pytest.raises(ConfigError, match=r"c.yaml: key 'tracker.host': 'nowhere'"):
        make_tracker(cfg, "nowhere")


@pytest.mark.parametrize("change, line, key, text", [
    ({"port": 70000}, 5, "tracker.port", "must be in 1…65535"),
    ({"port": "'x'"}, 5, "tracker.port", "expected an integer"),
    ({"marker": "[1]"}, 9, "tracker.tools.marker", "expected a device name"),
    ({"options": "{timeout_s: 100}"}, 7, "tracker.options.timeout_s",
     "expected a number > 0 and ≤ 60, got 100"),
    ({"options": "{retries: 2}"}, 7, "tracker.options",
     "unknown key 'retries' for driver 'lab'; expected one of: timeout_s"),
    ({"options": "{host: 10.0.0.1}"}, 7, "tracker.options.host", "set tracker.host instead"),
])
def test_the_drivers_own_keys_are_named_with_their_line(lab: None, tmp_path: Path,
                                                       change: dict[str, Any], line: int,
                                                       key: str, text: str) -> None:
    p = _lab(tmp_path, **change)
    with pytest.raises(ConfigError) as e:
        load_config(p)
    assert str(e.value).startswith(f"{p}, line {line}: key '{key}': "), str(e.value)
    assert text in str(e.value)


def test_an_unknown_tracker_key_names_the_drivers_keys(lab: None, tmp_path: Path) -> None:
    p = _write(tmp_path, LAB_YAML.format(port=1, options="{}", marker="M")
               + "  baud: 115200\n")
    with pytest.raises(ConfigError) as e:
        load_config(p)
    assert str(e.value) == (f"{p}, line 11: key 'tracker.baud': unknown key for driver 'lab'; "
                            "expected one of: driver, frame_rate_hz, host, options, port, tools")
    ndi = {"tracker": {"port": "/dev/ttyUSB0", "tools": {"marker": ROM}, "host": "x"}}
    with pytest.raises(ConfigError) as e:
        parse_config(ndi, "rig.yaml")
    assert str(e.value) == ("rig.yaml: key 'tracker.host': unknown key for driver 'ndi'; "
                            "expected one of: baud, driver, frame_rate_hz, log_wire, options, "
                            "port, reply, tools")


def test_an_ndi_key_error_names_its_line(tmp_path: Path) -> None:
    p = _write(tmp_path, f"tracker:\n  driver: ndi\n  port: /dev/ttyUSB0\n  baud: 1234\n"
                         f"  tools: {{marker: {ROM}}}\n  options: {{reset: false}}\n")
    with pytest.raises(ConfigError, match=rf"^{p}, line 4: key 'tracker.baud': expected a "
                                          r"COMM rate .*921600.*got 1234$"):
        load_config(p)
    p.write_text(p.read_text().replace("baud: 1234", "baud: 921600")
                 .replace("reset: false", "reset: maybe"))
    with pytest.raises(ConfigError, match=rf"^{p}, line 6: key 'tracker.options.reset': "
                                          r"expected true or false or null, got 'maybe'$"):
        load_config(p)


def test_the_old_ndi_reply_option_word_names_its_new_spelling(tmp_path: Path) -> None:
    """The NDI reply option word was ``tracker.options.options``; it is
    ``tracker.options.reply_options`` now: the old spelling is refused naming file, line and
    the new one, and the new one reaches the driver."""
    p = _write(tmp_path, f"tracker:\n  driver: ndi\n  port: /dev/ttyUSB0\n"
                         f"  tools: {{marker: {ROM}}}\n  options:\n    options: 1\n")
    with pytest.raises(ConfigError) as e:
        load_config(p)
    assert str(e.value) == (f"{p}, line 6: key 'tracker.options.options': moved for driver "
                            "'ndi': write it as tracker.options.reply_options (docs/configs.md)")
    p.write_text(p.read_text().replace("    options: 1", "    reply_options: 1"))
    tr = make_tracker(load_config(p))
    assert tr.reply_options == 1  # type: ignore[attr-defined]


def test_a_tracker_port_override_is_checked_against_the_wire_log(tmp_path: Path) -> None:
    cfg = parse_config({"tracker": {"port": "/dev/ttyUSB0", "tools": {"marker": ROM},
                                    "log_wire": str(tmp_path / "wire.log")}}, "rig.yaml")
    with pytest.raises(ConfigError, match="rig.yaml: key 'tracker.log_wire': .*serial device"):
        make_tracker(cfg, "socket://127.0.0.1:8765")


# --- robot and force-torque drivers declare their options ------------------------------------

def _robot(driver: str, options: dict[str, Any]) -> dict[str, Any]:
    return {"robot": {"driver": driver, "host": "192.0.2.1", "options": options},
            "safety": SAFE}


@pytest.mark.parametrize("data, key, text", [
    (_robot("denso", {"manual_reset": "yes"}), "robot.options.manual_reset",
     "expected true or false, got 'yes'"),
    (_robot("denso", {"halt_timeout_s": 0}), "robot.options.halt_timeout_s",
     "expected a number > 0 and ≤ 3600, got 0"),
    (_robot("denso", {"ext_speed_percent": 150}), "robot.options.ext_speed_percent",
     "expected a number in 0.01…100"),
    (_robot("denso", {"watchdog_ms": 1.5}), "robot.options.watchdog_ms",
     "expected an integer in 0…3600000 or null"),
    (_robot("franka", {"auto_recover": 1}), "robot.options.auto_recover",
     "expected true or false, got 1"),
    (_robot("franka", {"realtime": "true"}), "robot.options.realtime", "expected true or false"),
    (_robot("franka", {"timeout_s": -1}), "robot.options.timeout_s", "expected a number > 0"),
    (_robot("franka", {"upload_script": True}), "robot.options",
     "unknown key 'upload_script' for driver 'franka'; expected one of: auto_recover, "
     "realtime, timeout_s"),
    (_robot("ur", {"ur_cap_port": 0}), "robot.options.ur_cap_port",
     "expected an integer in 1…65535"),
    (_robot("ur", {"frequency_hz": 1000}), "robot.options.frequency_hz",
     "expected a number > 0 and ≤ 500 or null, got 1000"),
    ({"ft": {"driver": "ur_wrench", "options": {"kind": "flange"}}}, "ft.options.kind",
     "expected 'raw' or 'tcp', got 'flange'"),
    ({"ft": {"driver": "ur_wrench", "counts_per_force": 1}}, "ft.counts_per_force",
     "unknown key for driver 'ur_wrench'"),
    ({"ft": {"driver": "ati", "host": "192.0.2.7", "counts_per_force": 1,
             "counts_per_torque": 1, "options": {"max_lost_share": 1.0}}},
     "ft.options.max_lost_share", "expected a number ≥ 0 and < 1, got 1.0"),
])
def test_driver_options_are_checked_at_load(data: dict[str, Any], key: str, text: str) -> None:
    with pytest.raises(ConfigError) as e:
        parse_config(data, "rig.yaml")
    assert str(e.value).startswith(f"rig.yaml: key '{key}': "), str(e.value)
    assert text in str(e.value)


def test_declared_options_reach_the_drivers() -> None:
    robot = make_robot(parse_config(_robot("denso", {"manual_reset": True,
                                                     "halt_timeout_s": 2}), "rig.yaml"))
    assert (robot.manual_reset, robot.halt_timeout_s) == (True, 2.0)  # type: ignore[attr-defined]
    ft = make_ft(parse_config({"ft": {"driver": "ati", "host": "192.0.2.7",
                                      "counts_per_force": 4e5, "counts_per_torque": 2.5e6,
                                      "options": {"max_lost_share": 0.2}}}, "rig.yaml"))
    assert (ft.counts_per_force, ft.counts_per_torque, ft.max_lost_share) == (  # type: ignore
        4e5, 2.5e6, 0.2)


def test_a_spec_without_settings_passes_options_to_the_constructor(monkeypatch) -> None:
    """A plugin's spec that names no settings class: no keys of its own, options unchecked
    until the constructor sees them."""
    spec = registry.DriverSpec("kuka", "robot", "tmscal.drivers.denso.robot:DensoRobot",
                               default_port=7000)
    monkeypatch.setitem(registry.SPECS, "kuka", spec)
    cfg = parse_config({"robot": {"driver": "kuka", "options": {"fig": 3}}, "safety": SAFE})
    assert cfg.robot is not None and cfg.robot.options == {"fig": 3}
    with pytest.raises(ConfigError, match=r"key 'robot.options': unknown key 'turbo'"):
        make_robot(parse_config({"robot": {"driver": "kuka", "options": {"turbo": 1}},
                                 "safety": SAFE}, "rig.yaml"))
    with pytest.raises(ConfigError, match=r"key 'robot.options.envelope'"):
        parse_config({"robot": {"driver": "kuka", "options": {"envelope": 1}},
                      "safety": SAFE}, "rig.yaml")


def test_a_settings_class_of_the_wrong_kind_is_refused(monkeypatch) -> None:
    spec = registry.DriverSpec("odd", "robot", "tmscal.drivers.denso.robot:DensoRobot",
                               settings=f"{__name__}:LabSettings")
    monkeypatch.setitem(registry.SPECS, "odd", spec)
    with pytest.raises(ConfigError, match=r"rig.yaml: key 'robot.driver': driver 'odd': "
                                          r"settings .*LabSettings.* is not a RobotSettings"):
        parse_config({"robot": {"driver": "odd"}, "safety": SAFE}, "rig.yaml")
