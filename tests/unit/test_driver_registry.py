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

BUILTIN = [s.name for s in registry.BUILTIN]


@pytest.mark.parametrize("name", BUILTIN)
def test_registered_driver_fills_its_contract(name):
    spec = registry.get_spec(name)
    cls = driver_class(name)
    assert issubclass(cls, {"robot": Robot, "tracker": Tracker, "ft": ForceTorque}[spec.kind])
    assert not inspect.isabstract(cls), f"{cls.__name__} leaves hooks unimplemented"
    assert cls.name == name


@pytest.mark.parametrize("name", BUILTIN)
def test_registered_mock_loads(name):
    spec = registry.get_spec(name)
    assert spec.mock is not None and inspect.isclass(spec.load_mock())
    assert inspect.isclass(spec.load_mock("mock_faults"))
    if spec.mock_volume is not None:
        assert inspect.isclass(spec.load_mock("mock_volume"))


def test_names_by_kind():
    assert registry.driver_names("robot")[:2] == ["ur", "denso"]
    assert registry.driver_names("tracker") == ["ndi", "igtl"]
    with pytest.raises(ConfigError, match=r"unknown tracker driver 'ur'; known tracker drivers"):
        registry.get_spec("ur", "tracker")


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
    assert registry.driver_names("robot") == ["ur", "denso", "franka", "kuka"]


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
                                          r"franka, igtl, ndi, ur, ur_wrench"):
        driver_class("kuka")


def test_robot_refuses_before_sending(monkeypatch):
    """The base class checks the envelope and speed before the driver's hook runs."""
    import numpy as np

    from tmscal.drivers.base import Envelope
    from tmscal.errors import SafetyError

    sent = []

    class Probe(Robot):
        name = "probe"

        def _open(self): ...
        def _close(self): ...
        def _flange_pose(self): return np.eye(4)
        def _move_to(self, pose, speed_mm_s, accel_mm_s2): sent.append((pose, speed_mm_s))
        def _stop(self): ...

    env = Envelope(center=np.eye(4), max_offset_mm=10, max_speed_mm_s=50)
    with Probe(envelope=env, speed_mm_s=20) as r:
        far = np.eye(4)
        far[0, 3] = 11
        with pytest.raises(SafetyError, match="offset from P0 11.0 mm > max_offset_mm 10"):
            r.move_to(far)
        with pytest.raises(SafetyError, match="speed 60.0 mm/s > max_speed_mm_s 50"):
            r.move_to(np.eye(4), 60.0)
        near = np.eye(4)
        near[0, 3] = 9
        r.move_to(near)
    assert len(sent) == 1 and sent[0][1] == 20


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
