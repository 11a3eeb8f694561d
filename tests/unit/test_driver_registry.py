"""Every registered driver loads by name and fills the contract; unknown names are listed."""

import inspect

import pytest

from tmscal.drivers.base import DRIVERS, ConfigError, Robot, Tracker, driver_class


@pytest.mark.parametrize("name", sorted(DRIVERS))
def test_registered_driver_fills_its_contract(name):
    cls = driver_class(name)
    assert issubclass(cls, (Robot, Tracker))
    assert not inspect.isabstract(cls), f"{cls.__name__} leaves hooks unimplemented"
    assert cls.name == name


def test_unknown_driver_lists_the_known_ones():
    with pytest.raises(ConfigError, match=r"unknown driver 'kuka'; known drivers: denso, ndi, ur"):
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
        def _move_to(self, pose, speed_mm_s): sent.append((pose, speed_mm_s))
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
