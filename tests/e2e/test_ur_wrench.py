"""End to end: the UR e-Series wrench through the real ur_rtde library (URWrench, and
URRobot.wrench) from the UR mock, whose ft_raw_wrench and actual_TCP_force come from the sim
rig's gravity wrench plus noise.

The rig (no arm) holds a 1.5 kg load 60 mm along the flange z axis; the flange is rotated
90° about the base x axis (base z up). By hand, m g = 1.5 · 9.80665 N:
ft_raw_wrench (flange frame) = (0, −m g, 0, 0.06 m g, 0, 0);
actual_TCP_force (base frame) = the same rotated into the base: (0, 0, −m g, 0.06 m g, 0, 0)
with no payload set, and zero with the load set as the payload.

ur_rtde's constructors hold the GIL, so the client side runs in a child process
(``tests.child.run_child``) as in tests/e2e/test_ur_robot.py.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

if __name__ != "__main__":
    import pytest

    pytest.importorskip("rtde_receive")
    pytestmark = pytest.mark.e2e

from tests.child import child_main, run_child
from tests.rigs import unique_host
from tmscal.geometry import make_pose, rot_x
from tmscal.mocks.clock import FAST
from tmscal.mocks.ur import URMock
from tmscal.mocks.wrench import URWrenchOutputs, gravity_wrench_source
from tmscal.sim.rig import Noise, SimRig, tms_rig_truth

MG = 1.5 * 9.80665
RAW = np.array([0.0, -MG, 0.0, 0.06 * MG, 0.0, 0.0])
TCP_NO_PAYLOAD = np.array([0.0, 0.0, -MG, 0.06 * MG, 0.0, 0.0])
SIGMA = np.array([0.33] * 3 + [0.066] * 3)    # N, N·m per channel
N = 200


def _mock(host: str, payload_kg: float = 0.0) -> URMock:
    rig = SimRig(tms_rig_truth(), noise=Noise.none(),
                 start=make_pose(rot_x(math.pi / 2), [500.0, 0.0, 400.0]))
    mock = URMock(rig, host=host, clock=FAST)
    mock.wrench = URWrenchOutputs(gravity_wrench_source(rig), noise_n=0.33, noise_nm=0.066,
                                  payload_kg=payload_kg, payload_cog_mm=(0.0, 0.0, 60.0),
                                  seed=5)
    return mock


def _within_noise(mean: Any, want: np.ndarray) -> None:
    """The mean of N samples is within 4 standard errors of the source on every channel."""
    err = np.abs(np.array(mean) - want)
    assert np.all(err <= 4 * SIGMA / math.sqrt(N)), (np.array(mean), want)


def test_ur_wrench_raw_and_tcp_equal_the_rig_within_noise() -> None:
    with _mock(unique_host()) as mock:
        res = run_child(__file__, "sensor", mock.host, {"n": N})
    assert res["error"] is None, res["error"]
    assert res["identity"]["frame"] == "flange" and res["identity"]["variable"] == \
        "ft_raw_wrench"
    _within_noise(res["raw_mean"], RAW)
    _within_noise(res["tcp_mean"], TCP_NO_PAYLOAD)
    # the samples are noisy, independent draws (not one value repeated)
    sd = np.array(res["raw_sd"])
    assert np.all(sd > 0.5 * SIGMA) and np.all(sd < 1.5 * SIGMA)


def test_tcp_force_is_payload_compensated() -> None:
    with _mock(unique_host(), payload_kg=1.5) as mock:
        res = run_child(__file__, "sensor", mock.host, {"n": N})
    assert res["error"] is None, res["error"]
    _within_noise(res["tcp_mean"], np.zeros(6))
    _within_noise(res["raw_mean"], RAW)


def test_urrobot_wrench_reads_the_same() -> None:
    with _mock(unique_host()) as mock:
        res = run_child(__file__, "robot", mock.host, {"n": N})
    assert res["error"] is None, res["error"]
    _within_noise(res["raw"], RAW)
    _within_noise(res["tcp"], TCP_NO_PAYLOAD)


def test_mock_without_a_wrench_source_reads_zero() -> None:
    rig = SimRig(tms_rig_truth(), noise=Noise.none())
    with URMock(rig, host=unique_host(), clock=FAST) as mock:
        res = run_child(__file__, "sensor", mock.host, {"n": 3})
    assert res["error"] is None, res["error"]
    assert res["raw_mean"] == [0.0] * 6 and res["tcp_mean"] == [0.0] * 6


# --- child process ------------------------------------------------------------------------------

def _child(scenario: str, host: str, args: dict[str, Any], res: dict[str, Any]) -> None:
    res["error"] = None
    try:
        if scenario == "sensor":
            from tmscal.drivers.ur.wrench import URWrench

            with URWrench(host, "raw") as raw:
                res["identity"] = raw.identity()
                w = raw.read(args["n"])
            with URWrench(host, "tcp") as tcp:
                t = tcp.read(args["n"])
            res.update(raw_mean=w.mean(0).tolist(), raw_sd=w.std(0, ddof=1).tolist()
                       if len(w) > 1 else None, tcp_mean=t.mean(0).tolist())
        else:
            from tmscal.drivers.ur.robot import URRobot

            with URRobot(host, timeout_s=10.0) as robot:
                res["raw"] = robot.wrench("raw", args["n"]).tolist()
                res["tcp"] = robot.wrench("tcp", args["n"]).tolist()
    except Exception as e:  # reported to the parent
        res["error"] = f"{type(e).__name__}: {e}"


if __name__ == "__main__":
    child_main(_child)


def test_config_ft_ur_wrench_served_by_the_ur_mock(tmp_path: Any) -> None:
    """A config with ``ft: {driver: ur_wrench, host: robot}``: ``tmscal mock`` (a child
    process) serves the rig's gravity wrench through the UR mock; make_ft reads it at the
    robot's address. The rig's P0 turns the flange, so by hand: raw = Rᵀ(0, 0, −m g) and
    c × that, R the flange's rotation at P0 (the mock reports P0 as the flange pose)."""
    from tests.rigs import NOISE_FREE_MOCK, write_config
    from tmscal.acquisition.devices import make_ft
    from tmscal.config import load_config
    from tmscal.mocks.launch import spawn_mock_rig
    from tmscal.sim.rig import TMS_RIG_P0

    path = write_config(tmp_path, "mock-ur-polaris.yaml",
                        ft={"driver": "ur_wrench", "host": "robot", "samples": 20},
                        mock={"noise": NOISE_FREE_MOCK, "ft": {"noise_n": 0.0}})
    cfg = load_config(path)
    with spawn_mock_rig(path) as proc:
        assert proc.endpoints["ft"] == proc.endpoints["robot"]
        with make_ft(cfg) as ft:
            assert ft.identity()["host"] == cfg.robot.host
            w = ft.read(20).mean(axis=0)
    f = TMS_RIG_P0[:3, :3].T @ [0.0, 0.0, -MG]
    np.testing.assert_allclose(w, np.concatenate([f, np.cross([0.0, 0.0, 0.060], f)]),
                               atol=1e-9)
