"""The force-torque sensor's config section, make_ft and the ForceTorque contract: every bad
value is one ConfigError naming the key, before anything opens."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from tmscal.acquisition.devices import make_ft
from tmscal.config import parse_config
from tmscal.drivers.ati.sensor import ATINetFT
from tmscal.drivers.base import DeviceError, ForceTorque
from tmscal.errors import ConfigError

SAFETY = {"max_offset_mm": 100, "max_rotation_deg": 10, "workspace_min_mm": [0, 0, 0],
          "workspace_max_mm": [900, 900, 900], "max_speed_mm_s": 200, "max_accel_mm_s2": 1000,
          "tool_points_mm": [[0, 0, 100]]}
ATI = {"driver": "ati", "host": "192.0.2.7", "counts_per_force": 1e6, "counts_per_torque": 2e5}


def _cfg(ft: Any, **more: Any) -> Any:
    return parse_config({"ft": ft, **more}, "rig.yaml")


def test_ati_section_builds_the_driver_with_the_calibration() -> None:
    cfg = _cfg({**ATI, "samples": 7, "options": {"timeout_s": 0.25}})
    assert cfg.ft.samples == 7
    ft = make_ft(cfg)
    assert isinstance(ft, ATINetFT) and not ft.is_open
    assert (ft.host, ft.port, ft.timeout_s) == ("192.0.2.7", 49152, 0.25)
    assert (ft.counts_per_force, ft.counts_per_torque) == (1e6, 2e5)
    assert make_ft(cfg, host="127.0.0.5", port=40000).identity()["port"] == 40000


def test_ur_wrench_takes_the_robot_address() -> None:
    cfg = _cfg({"driver": "ur_wrench", "options": {"kind": "tcp"}},
               robot={"driver": "ur", "host": "192.0.2.9"}, safety=SAFETY)
    ft = make_ft(cfg)
    assert ft.identity() == {"driver": "ur_wrench", "host": "192.0.2.9", "kind": "tcp",
                             "variable": "actual_TCP_force", "frame": "base"}


@pytest.mark.parametrize("ft, key", [
    ({"driver": "kuka"}, "ft.driver"),
    ({"driver": "ur"}, "ft.driver"),
    ({**ATI, "samples": 0}, "ft.samples"),
    ({**ATI, "counts_per_force": 0}, "ft.counts_per_force"),
    ({**ATI, "counts_per_torque": float("nan")}, "ft.counts_per_torque"),
    ({**ATI, "counts_per_torque": "1e6"}, "ft.counts_per_torque"),
    ({**ATI, "port": 70000}, "ft.port"),
    ({**ATI, "host": ""}, "ft.host"),
    ({**ATI, "colour": 1}, "ft.colour"),
    ({**ATI, "options": {"counts_per_force": 1}}, "ft.options.counts_per_force"),
    ({**ATI, "options": "fast"}, "ft.options"),
    ("ati", "ft"),
])
def test_bad_ft_section_names_the_key(ft: Any, key: str) -> None:
    with pytest.raises(ConfigError, match=f"rig.yaml: key '{key}'"):
        _cfg(ft)


@pytest.mark.parametrize("mock, key", [
    ({"ft": {"noise": 1}}, "mock.ft.noise"),
    ({"ft": {"faults": [1]}}, "mock.ft.faults"),
    ({"ft": 3}, "mock.ft"),
])
def test_bad_mock_ft_names_the_key(mock: Any, key: str) -> None:
    with pytest.raises(ConfigError, match=f"key '{key}'"):
        parse_config({"mock": mock}, "rig.yaml")


@pytest.mark.parametrize("ft, more, key, text", [
    ({"driver": "ati", "host": "192.0.2.7", "counts_per_torque": 1e6}, {}, "ft.counts_per_force",
     "cfgcpf"),
    ({"driver": "ati", "counts_per_force": 1, "counts_per_torque": 1}, {}, "ft.host",
     "own address"),
    ({"driver": "ur_wrench"}, {}, "ft.host", "no robot section"),
    ({**ATI, "options": {"bogus": 1}}, {}, "ft.options", "bogus"),
])
def test_make_ft_refuses_before_opening(ft: Any, more: Any, key: str, text: str) -> None:
    with pytest.raises(ConfigError, match=f"key '{key}'.*{text}"):
        make_ft(_cfg(ft, **more))


def test_no_ft_section() -> None:
    with pytest.raises(ConfigError, match="key 'ft': this command needs"):
        make_ft(parse_config({}, "rig.yaml"))


class _Fixed(ForceTorque):
    name = "fixed"

    def _open(self) -> None: ...

    def _close(self) -> None: ...

    def _read(self, n: int) -> np.ndarray:
        return np.arange(6.0)[None].repeat(n, axis=0)


def test_force_torque_contract() -> None:
    ft = _Fixed()
    with pytest.raises(DeviceError, match="not open"):
        ft.read(1)
    with ft:
        assert ft.read(3).shape == (3, 6)
        for bad in (0, -1, 1.5, True):
            with pytest.raises(ValueError, match="integer n ≥ 1"):
                ft.read(bad)  # type: ignore[arg-type]
    assert not ft.is_open


@pytest.mark.parametrize("kw, text", [
    ({"counts_per_force": 0}, "counts_per_force"), ({"counts_per_torque": -1}, "counts_per_torque"),
    ({"port": 0}, "port"), ({"timeout_s": 0}, "timeout_s"), ({"max_lost_share": 1.0},
                                                            "max_lost_share"),
])
def test_ati_constructor_refuses(kw: dict[str, Any], text: str) -> None:
    args = {"host": "127.0.0.1", "counts_per_force": 1e6, "counts_per_torque": 1e6, **kw}
    with pytest.raises(ValueError, match=text):
        ATINetFT(**args)
