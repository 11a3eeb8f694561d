"""End to end: a mock rig that stands differently from its calibration truth (``mock.changes``)
and one that changes during a run (``mock.events``), through the real drivers and wire
protocols.

* ``mock.changes.tracker``: the UR + Polaris mock in a child process (``tmscal mock``), ~20
  poses acquired and solved (QR36): the solved Z is the CHANGED truth's, and differs from the
  unchanged truth's by the change (2 mm, 0.5°); X and Y are the unchanged ones.
* ``mock.events``: the Polaris mock on the fast clock, read by the NDI driver: the tracker's
  move shows from the frame at which the tracker's virtual time (frames served / frame rate)
  reaches the event's time, and not before.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.rigs import NOISE_FREE_MOCK, endpoints_kwargs
from tmscal.acquisition.devices import make_tracker
from tmscal.acquisition.run import acquire
from tmscal.config import load_config
from tmscal.geometry import invert, rotation_angle
from tmscal.mocks.launch import build_sim_rig, spawn_mock_rig, start_mock_rig
from tmscal.session import read_session
from tmscal.sim import TMS_RIG_P0, tms_rig_truth
from tmscal.solving.solve import solve

CHANGE = {"mm": [2.0, 0.0, 0.0], "deg": [0.0, 0.0, 0.5]}


def _trans_rot(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(‖t(a) − t(b)‖ mm, the angle between their rotations, deg)."""
    return (float(np.linalg.norm(a[:3, 3] - b[:3, 3])),
            math.degrees(float(rotation_angle(a[:3, :3].T @ b[:3, :3]))))


@pytest.mark.e2e
def test_acquire_on_a_moved_tracker_solves_the_changed_truth(tmp_path, mock_config):
    cfg_path = mock_config("mock-ur-polaris.yaml", plan={"poses": 20},
                           sampling={"samples": 10}, mock={"changes": {"tracker": CHANGE}})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        res = acquire(load_config(cfg_path), out, **endpoints_kwargs(mp.endpoints))
    assert (res.recorded, res.skipped) == (20, 0)
    s = read_session(out)
    # the header's config carries the change, so a reader knows how the rig stood
    assert s.header["config"]["mock"]["changes"] == {"tracker": CHANGE}
    truth = build_sim_rig(load_config(cfg_path)).truth   # the child built the same rig
    calibrated = tms_rig_truth()                         # what the rig was before the change
    # the rig's truth is the calibrated one with the change: 2 mm along base x, 0.5° about z
    assert _trans_rot(truth.Z, calibrated.Z) == pytest.approx((2.0, 0.5), abs=1e-9)
    s.header["truth"] = truth.as_dict()
    r = solve(s, method="qr36")
    dz_t, dz_r = _trans_rot(r.Z, truth.Z)
    # noise: 0.05 mm fiducials, 0.05 mm / 0.05° robot, 10 frames per pose, 20 poses
    assert dz_t < 0.5 and dz_r < 0.05, (dz_t, dz_r)
    assert r.truth["Z"]["trans_mm"] == pytest.approx(dz_t)   # the header's truth is the changed
    moved_t, moved_r = _trans_rot(r.Z, calibrated.Z)
    assert abs(moved_t - 2.0) < 0.5 and abs(moved_r - 0.5) < 0.05, (moved_t, moved_r)
    for got, want in ((r.X, calibrated.X), (r.Y, calibrated.Y)):   # marker and coil unmoved
        t, a = _trans_rot(got, want)
        assert t < 0.5 and a < 0.1, (t, a)


@pytest.mark.e2e
def test_an_event_shows_from_the_fast_clock_frame_of_its_time(mock_config):
    rate = 60.0
    at_s = 100 / rate                      # the tracker's virtual time of frame 100
    base = mock_config("mock-polaris.yaml",
                       mock={"clock": "fast", "noise": NOISE_FREE_MOCK,
                             "events": [{"at_s": at_s, "move": "tracker", **CHANGE}]})
    cfg0 = load_config(base)
    assert cfg0.tracker is not None and cfg0.tracker.frame_rate_hz == rate
    with start_mock_rig(cfg0, tracker_transport="pty") as mr:
        before = mr.rig.truth
        with make_tracker(cfg0, mr.endpoints["tracker"]) as tracker:
            served = round(mr.devices[0].tracker_time_s() * rate)  # frames read by open()
            assert served < 90
            seen = [tracker.read().pose("marker") for _ in range(120 - served)]
        after = mr.rig.truth
        fired = list(mr.rig.fired)
    rest = invert(before.Z) @ TMS_RIG_P0 @ before.X
    moved = invert(after.Z) @ TMS_RIG_P0 @ after.X
    assert _trans_rot(after.Z, before.Z) == pytest.approx((2.0, 0.5), abs=1e-9)
    # frame k (k = served + 1, …) is read at k / 60 s: k < 100 before the event, k ≥ 100 after
    k = np.arange(served + 1, 121)
    for ki, pose in zip(k, seen, strict=True):
        want = rest if ki < 100 else moved
        np.testing.assert_allclose(pose[:3, 3], want[:3, 3], atol=1e-3)   # BX: float32
    assert len(fired) == 1 and fired[0][1] == pytest.approx(at_s)
