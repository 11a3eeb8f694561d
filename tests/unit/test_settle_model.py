"""The sim rig's settling model (``sim.Settle``): a damped oscillation of the true flange after
each move that the tracker sees and the controller does not report; its time base (a fake
clock here; the tracker's frames on the fast clock); the ``mock.settle`` config key."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tests.rigs import quiet_tms_rig
from tmscal.config import load_config
from tmscal.errors import ConfigError
from tmscal.geometry import invert, make_pose
from tmscal.mocks.clock import FAST
from tmscal.mocks.launch import build_sim_rig, start_mock_rig
from tmscal.mocks.polaris.frames import FrameSource
from tmscal.mocks.polaris.model import PolarisFaults
from tmscal.sim import TMS_RIG_P0, Noise, Settle, SimRig

AMP, TAU, FREQ = 0.3, 0.25, 4.0


class FakeTime:
    """A clock the test sets by hand (seconds)."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _rig(settle: Settle | None, seed: int = 0) -> tuple[SimRig, FakeTime]:
    clock = FakeTime()
    rig = quiet_tms_rig(settle=settle, time_s=clock, rng=np.random.default_rng(seed))
    return rig, clock


def _target(dx: float = 20.0) -> np.ndarray:
    return TMS_RIG_P0 @ make_pose(np.eye(3), [dx, -5.0, 3.0])


def _offsets(rig: SimRig, clock: FakeTime, times: np.ndarray) -> np.ndarray:
    """Offset (n, 3) of the tracked marker from its resting pose, in the base frame, mm."""
    t0 = clock.t
    out = []
    for t in times:
        clock.t = t0 + t
        T = rig.truth.Z @ rig.true_body("marker") @ invert(rig.truth.X)
        out.append(T[:3, 3] - rig.flange[:3, 3])
    clock.t = t0
    return np.array(out)


def test_settle_validates_its_fields() -> None:
    for bad, field in ((dict(amplitude_mm=-0.1), "amplitude_mm"), (dict(tau_s=0.0), "tau_s"),
                       (dict(freq_hz=math.nan), "freq_hz"), (dict(rotation_deg=90.0),
                                                            "rotation_deg"),
                       (dict(tau_s=True), "tau_s"), (dict(amplitude_mm="0.3"), "amplitude_mm")):
        with pytest.raises(ValueError, match=field):
            Settle(**bad)


def test_without_settle_the_flange_is_still_after_a_move() -> None:
    rig, clock = _rig(None)
    rig.move_flange(_target())
    rest = invert(rig.truth.Z) @ rig.flange @ rig.truth.X
    for dt in np.linspace(0.0, 2.0, 9):
        clock.t += dt
        assert np.array_equal(rig.true_body("marker"), rest)


def test_oscillation_decays_with_the_stated_time_constant() -> None:
    rig, clock = _rig(Settle(AMP, TAU, FREQ))
    rig.move_flange(_target())
    # at the cosine's peaks t = k/f the offset is A·exp(−t/τ): fit τ and A from the log
    peaks = np.arange(0, 6) / FREQ
    mag = np.linalg.norm(_offsets(rig, clock, peaks), axis=1)
    slope, intercept = np.polyfit(peaks, np.log(mag), 1)
    assert -1.0 / slope == pytest.approx(TAU, rel=1e-6)
    assert math.exp(intercept) == pytest.approx(AMP, rel=1e-6)
    # at the cosine's zeros (t = (k + ½)/(2f)) the flange passes through its resting pose
    zeros = (np.arange(0, 4) + 0.5) / (2 * FREQ)
    assert np.abs(_offsets(rig, clock, zeros)).max() < 1e-9


def test_oscillation_is_along_one_direction_per_move_and_a_new_one_each_move() -> None:
    rig, clock = _rig(Settle(AMP, TAU, FREQ), seed=3)
    dirs = []
    for k in range(3):
        rig.move_flange(_target(10.0 * k))
        d = _offsets(rig, clock, np.array([0.0, 0.05, 0.3, 0.55]))
        u = d[0] / np.linalg.norm(d[0])
        # every offset of this move lies on the line of u (rank one)
        assert np.abs(np.cross(d, u)).max() < 1e-12
        dirs.append(u)
        clock.t += 1.0
    assert abs(dirs[0] @ dirs[1]) < 0.999 and abs(dirs[1] @ dirs[2]) < 0.999


def test_directions_are_isotropic_over_many_moves() -> None:
    """Seeded: over 2000 moves the mean direction is ≈ 0 and the second moment ≈ I/3
    (tolerance 0.05: ~5 standard errors)."""
    rig, clock = _rig(Settle(AMP, TAU, 0.0), seed=11)
    us = []
    for _ in range(2000):
        rig.move_flange(TMS_RIG_P0)
        d = _offsets(rig, clock, np.array([0.0]))[0]
        us.append(d / np.linalg.norm(d))
    U = np.array(us)
    assert np.abs(U.mean(axis=0)).max() < 0.05
    assert np.abs(U.T @ U / len(U) - np.eye(3) / 3).max() < 0.05


def test_rotation_option_turns_the_flange_about_its_origin() -> None:
    rig, clock = _rig(Settle(0.0, TAU, FREQ, rotation_deg=0.5))
    rig.move_flange(_target())
    A = rig.truth.Z @ rig.true_body("marker") @ invert(rig.truth.X)
    R = rig.flange[:3, :3].T @ A[:3, :3]
    angle = math.degrees(math.acos(min(1.0, (np.trace(R) - 1) / 2)))
    assert angle == pytest.approx(0.5, rel=1e-6)
    np.testing.assert_allclose(A[:3, 3], rig.flange[:3, 3], atol=1e-9)


def test_reported_pose_does_not_oscillate_and_quiet_means_exactly_still() -> None:
    rig, clock = _rig(Settle(AMP, TAU, FREQ))
    target = _target()
    rig.move_flange(target)
    assert np.abs(_offsets(rig, clock, np.array([0.0]))).max() > 0.1
    np.testing.assert_array_equal(rig.reported_flange(), target)
    clock.t += Settle(AMP, TAU, FREQ).quiet_after_s
    assert np.array_equal(rig.true_body("marker"),
                          invert(rig.truth.Z) @ rig.flange @ rig.truth.X)


def test_follow_puts_the_true_flange_on_the_path_until_the_move_ends() -> None:
    rig, clock = _rig(Settle(AMP, TAU, FREQ))
    mid = _target(7.0)
    rig.follow(lambda: mid)
    A = rig.truth.Z @ rig.true_body("marker") @ invert(rig.truth.X)
    np.testing.assert_allclose(A, mid, atol=1e-9)   # noise-free rig: no positioning error
    rig.move_flange(_target(20.0))
    assert np.abs(_offsets(rig, clock, np.array([0.0]))).max() > 0.1   # settling again


def test_fast_clock_time_base_advances_with_frames_only() -> None:
    rig = quiet_tms_rig(settle=Settle(AMP, TAU, FREQ))
    frames = FrameSource(rig, FAST, 60.0, None, PolarisFaults(), np.random.default_rng(0), 0.1)
    rig.time_s = frames.time_s
    rig.move_flange(_target())
    handles = [(1, "marker")]
    first = frames.records(handles, 0)[0][0]
    assert frames.time_s() == pytest.approx(1 / 60)
    frames.restart(observations=False)          # TSTART: frame numbers restart, time does not
    xs = [first.translation_mm]
    for _ in range(59):
        xs.append(frames.records(handles, 0)[0][0].translation_mm)
    assert frames.time_s() == pytest.approx(1.0)
    dev = np.linalg.norm(np.array(xs) - (invert(rig.truth.Z) @ rig.flange @ rig.truth.X)[:3, 3],
                         axis=1)
    # the first frame is 1/60 s into the oscillation, the last 1 s (= 4 τ) into it
    assert dev[0] > 0.5 * AMP * math.exp(-1 / 60 / TAU) * abs(math.cos(2 * math.pi * FREQ / 60))
    assert dev[-1] <= AMP * math.exp(-1.0 / TAU) + 1e-12
    assert dev[-1] < dev[0] / 10


def test_config_key_and_wiring(mock_config) -> None:
    path = mock_config("mock-ur-polaris.yaml",
                       mock={"settle": {"amplitude_mm": 0.3, "tau_s": 0.25, "freq_hz": 4}})
    cfg = load_config(path)
    rig = build_sim_rig(cfg)
    assert rig.settle == Settle(0.3, 0.25, 4.0)
    with start_mock_rig(cfg, tracker_transport="tcp") as mr:
        assert mr.rig.time_s is not None      # fast clock: the tracker's time
    plain = build_sim_rig(load_config(mock_config("mock-ur-polaris.yaml")))
    assert plain.settle is None


@pytest.mark.parametrize("settle, key", [({"tau_s": -1}, "tau_s"), ({"amp": 1}, "amp"),
                                         (3, "mapping")])
def test_bad_settle_key_is_a_config_error(mock_config, settle, key) -> None:
    path: Path = mock_config("mock-ur-polaris.yaml", mock={"settle": settle})
    with pytest.raises(ConfigError, match=rf"key 'mock.settle'.*{key}"):
        load_config(path)


def test_noise_free_rig_settles_to_the_commanded_pose() -> None:
    rig = SimRig(quiet_tms_rig().truth, noise=Noise.none(), settle=Settle(AMP, TAU, FREQ),
                 time_s=lambda: 0.0)
    rig.move_flange(_target())
    np.testing.assert_array_equal(rig.flange, _target())


def test_realtime_config_runs_on_the_real_clock_with_settling(configs_dir) -> None:
    cfg = load_config(configs_dir / "mock-ur-polaris-realtime.yaml")
    assert cfg.mock is not None and cfg.mock.clock == "real"
    assert build_sim_rig(cfg).settle == Settle(0.3, 0.25, 4.0)
    assert cfg.sampling.settle == "still" and cfg.sampling.settle_s == 1.0
    assert cfg.plan.poses == 500
    assert cfg.robot is not None
    assert cfg.robot.speed_mm_s <= cfg.safety.max_speed_mm_s
    assert cfg.robot.accel_mm_s2 <= cfg.safety.max_accel_mm_s2
