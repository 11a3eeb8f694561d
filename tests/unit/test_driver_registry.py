"""Every registered driver loads by name and fills the contract; unknown names are listed;
third-party drivers come in through the ``tmscal.drivers`` entry points; a missing extra is
one ``MissingExtraError``."""

import dataclasses
import inspect
from importlib.metadata import EntryPoint

import pytest

from tmscal import registry
from tmscal.drivers.base import ConfigError, ForceTorque, Robot, Tracker, driver_class
from tmscal.errors import MissingExtraError
from tmscal.registry import DriverSpec

BUILTIN = [(s.kind, s.name) for s in registry.BUILTIN]
IDS = [f"{n}/{k}" for k, n in BUILTIN]
#: the drivers without a protocol-level mock: in-process, they speak no wire protocol
IN_PROCESS = {"sim"}


@pytest.mark.parametrize("kind, name", BUILTIN, ids=IDS)
def test_registered_driver_fills_its_contract(kind, name):
    spec = registry.get_spec(name, kind)
    cls = driver_class(name, kind)
    assert spec.kind == kind
    assert issubclass(cls, {"robot": Robot, "tracker": Tracker, "ft": ForceTorque}[spec.kind])
    assert not inspect.isabstract(cls), f"{cls.__name__} leaves hooks unimplemented"
    assert cls.name == name


@pytest.mark.parametrize("kind, name", BUILTIN, ids=IDS)
def test_registered_mock_loads(kind, name):
    spec = registry.get_spec(name, kind)
    if name in IN_PROCESS:
        assert spec.mock is None
        with pytest.raises(ConfigError, match=f"driver '{name}' has no mock"):
            spec.load_mock()
        return
    assert spec.mock is not None and inspect.isclass(spec.load_mock())
    assert inspect.isclass(spec.load_mock("mock_faults"))
    if spec.mock_volume is not None:
        assert inspect.isclass(spec.load_mock("mock_volume"))


def test_names_by_kind():
    assert registry.driver_names("robot")[:2] == ["ur", "denso"]
    assert registry.driver_names("tracker") == ["ndi", "igtl", "sim"]
    with pytest.raises(ConfigError, match=r"unknown tracker driver 'ur'; known tracker drivers"):
        registry.get_spec("ur", "tracker")


def test_one_name_may_serve_two_kinds():
    """``sim`` is a robot and a tracker: each lookup by kind finds its own; without a kind
    the first registered (the robot); every name is listed once."""
    assert registry.get_spec("sim", "robot").cls.endswith(":SimRobot")
    assert registry.get_spec("sim", "tracker").cls.endswith(":SimTracker")
    assert registry.get_spec("sim").kind == "robot"
    assert registry.is_registered("sim", "tracker") and not registry.is_registered("sim", "ft")
    names = registry.driver_names()
    assert len(names) == len(set(names)) and "sim" in names
    with pytest.raises(ConfigError, match="unknown ft driver 'sim'"):
        registry.get_spec("sim", "ft")


def test_a_name_is_one_driver_within_its_kind(entry_points):
    other = DriverSpec("sim", "tracker", "x.y:Z")
    with pytest.raises(ConfigError, match="driver 'sim' is registered twice"):
        registry.register(other)
    # a new kind under a taken name gets its own slot and takes nothing from the others
    ft = registry.register(DriverSpec("sim", "ft", "x.y:FT"))
    assert registry.slot(ft) == "sim/ft" and registry.get_spec("sim", "ft") is ft
    assert registry.get_spec("sim", "tracker").cls.endswith(":SimTracker")


KUKA = DriverSpec("kuka", "robot", "tmscal.drivers.denso.robot:DensoRobot", default_port=7000)


def _kuka_factory():
    return KUKA


@pytest.fixture
def entry_points(monkeypatch):
    """Stands in for the installed ``tmscal.drivers`` entry points (reloaded per test)."""
    eps: list[EntryPoint] = []
    monkeypatch.setattr(registry.importlib.metadata, "entry_points",
                        lambda group: [e for e in eps if e.group == group])
    monkeypatch.setattr(registry, "SPECS", dict(registry.SPECS))
    monkeypatch.setattr(registry, "_entry_points_loaded", False)
    return eps


def _ep(name, value):
    return EntryPoint(name=name, value=value, group=registry.ENTRY_POINT_GROUP)


@pytest.mark.parametrize("value", [f"{__name__}:KUKA", f"{__name__}:_kuka_factory"])
def test_entry_point_registers_a_driver(entry_points, value):
    entry_points.append(_ep("kuka", value))
    assert registry.get_spec("kuka", "robot") is KUKA
    assert registry.driver_names("robot") == ["ur", "denso", "franka", "sim", "kuka"]


@pytest.mark.parametrize("value, match", [
    ("no_such_module_xyz:SPEC", "cannot be loaded"),
    (f"{__name__}:BUILTIN", "gives list, not a DriverSpec"),
    (f"{__name__}:UR_AGAIN", "reuses the name"),
])
def test_broken_entry_point_is_a_config_error_naming_it(entry_points, value, match):
    name = "ur" if "UR_AGAIN" in value else "broken"
    entry_points.append(_ep(name, value))
    with pytest.raises(ConfigError, match=rf"entry point '{name}'.*{match}"):
        registry.get_spec("kuka")


UR_AGAIN = dataclasses.replace(registry.get_spec("ur"), cls="x.y:Z")


def test_entry_point_name_must_match_the_spec(entry_points):
    entry_points.append(_ep("kuka2", f"{__name__}:KUKA"))
    with pytest.raises(ConfigError, match="entry point 'kuka2'.*names must match"):
        registry.driver_names()


def test_builtin_names_do_not_load_entry_points(entry_points):
    entry_points.append(_ep("broken", "no_such_module_xyz:SPEC"))
    assert registry.get_spec("denso").name == "denso"  # a broken plugin cannot hide a built-in


def test_missing_extra_is_one_error_type(monkeypatch):
    spec = dataclasses.replace(registry.get_spec("ur"), requires=("no_such_module_xyz",))
    with pytest.raises(MissingExtraError, match=r"driver 'ur' needs the optional extra 'ur'.*"
                       r"pip install 'tmscal\[ur\]'") as ei:
        spec.load()
    assert ei.value.extra == "ur" and isinstance(ei.value, ConfigError)
    spec = dataclasses.replace(spec, requires=(), cls="no_such_module_xyz:URRobot",
                               mock="no_such_module_xyz:URMock")
    with pytest.raises(MissingExtraError, match="driver 'ur'"):
        spec.load()
    with pytest.raises(MissingExtraError, match="'ur' mock"):
        spec.load_mock()


def test_spec_is_checked():
    with pytest.raises(ValueError, match="kind"):
        DriverSpec("x", "camera", "a:B")
    with pytest.raises(ValueError, match="module:Class"):
        DriverSpec("x", "robot", "a.B")


def test_unknown_driver_lists_the_known_ones():
    with pytest.raises(ConfigError, match=r"unknown driver 'kuka'; known drivers: ati, denso, "
                                          r"franka, igtl, ndi, sim, ur, ur_wrench"):
        driver_class("kuka")


def test_robot_refuses_before_sending():
    """The base class checks the envelope and speed before the driver's hook runs: the sim
    robot's rig sees only the move that passed."""
    import numpy as np

    from tmscal.drivers.base import Envelope
    from tmscal.drivers.sim.robot import SimRobot
    from tmscal.errors import SafetyError
    from tmscal.sim import TMS_RIG_P0

    env = Envelope(center=TMS_RIG_P0, max_offset_mm=10, max_speed_mm_s=50)
    with SimRobot(envelope=env, speed_mm_s=20, channel="refuses-before-sending") as r:
        far = TMS_RIG_P0.copy()
        far[0, 3] += 11
        with pytest.raises(SafetyError, match="offset from P0 11.0 mm > max_offset_mm 10"):
            r.move_to(far)
        with pytest.raises(SafetyError, match="speed 60.0 mm/s > max_speed_mm_s 50"):
            r.move_to(TMS_RIG_P0, 60.0)
        assert len(r.rig.moves) == 0 and r.moves_sent == 0
        near = TMS_RIG_P0.copy()
        near[0, 3] += 9
        route = r.move_to(near)
        assert [leg.speed_mm_s for leg in route.legs] == [20]
        assert len(r.rig.moves) == 1
        np.testing.assert_array_equal(r.rig.moves[0], near)


def test_config_accepts_an_entry_point_driver_and_builtins_despite_a_broken_one(entry_points):
    from tmscal.config import parse_config

    safety = {"max_offset_mm": 100, "max_rotation_deg": 10,
              "workspace_min_mm": [-1000, -1000, -1000], "workspace_max_mm": [1000, 1000, 1000],
              "max_speed_mm_s": 100, "max_accel_mm_s2": 500}
    entry_points.append(_ep("kuka", f"{__name__}:KUKA"))
    assert parse_config({"robot": {"driver": "kuka"}, "safety": safety}).robot.driver == "kuka"
    entry_points[:] = [_ep("broken", "no_such_module_xyz:SPEC")]
    registry._entry_points_loaded = False
    registry.SPECS.pop("kuka")
    assert parse_config({"robot": {"driver": "ur"}, "safety": safety}).robot.driver == "ur"
    with pytest.raises(ConfigError, match="entry point 'broken'"):
        parse_config({"robot": {"driver": "kuka"}, "safety": safety})
