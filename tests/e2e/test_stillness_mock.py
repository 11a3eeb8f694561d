"""End to end: settling by stillness against the mock rig's settling model.

The mock DENSO arm and the mock Polaris (real sockets and a pty, in this process) serve one
simulated rig whose coil swings after every move (``mock.settle``: a damped oscillation of
0.3 mm, τ 0.25 s, 4 Hz, as the issue describes a real arm). The robot's positioning noise is
off, so the coil comes to rest exactly at the commanded pose and the truth of every recorded
pose is known: B = Z⁻¹·A_cmd·X, C = Z⁻¹·A_cmd·Y. The same plan is acquired with
``settle: still`` and with a fixed short wait, and the recorded poses, spreads and sample
counts are compared with that truth (never durations).

The mocks run on the fast clock, where the rig's time is the tracker's (frames served / frame
rate): the swing decays only as frames are read, so a fixed wait is, for the swing, no wait
at all, and the runs are deterministic.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from tmscal.acquisition.run import acquire
from tmscal.config import load_config
from tmscal.geometry import invert
from tmscal.mocks.launch import start_mock_rig
from tmscal.session import read_session

from ..rigs import endpoints_kwargs

POSES = 12
SETTLE = {"amplitude_mm": 0.3, "tau_s": 0.25, "freq_hz": 4.0}
#: the mock's per-axis noise of a tracked origin is about 0.025 mm (0.05 mm fiducials, four
#: spheres): white noise alone gives a spread of about √3·0.025 ≈ 0.043 mm
NOISE = {"fiducial_sigma_mm": 0.05, "robot_rot_sigma_deg": 0.0, "robot_trans_sigma_mm": 0.0}
STILL = {"settle": "still", "settle_s": 2.0}
FIXED = {"settle": "fixed", "settle_s": 0.05}


def _run(mock_config, tmp_path: Path, sampling: dict) -> tuple[np.ndarray, list, list]:
    """Acquire the plan with these sampling options; returns the translation errors (mm) of
    every recorded B and C against the rig's truth, the marker's recorded spreads (mm) and
    sample counts."""
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           plan={"poses": POSES, "radius_mm": 20, "rotation_deg": 2},
                           sampling=sampling,
                           mock={"clock": "fast", "noise": NOISE, "settle": SETTLE})
    cfg = load_config(cfg_path)
    out = tmp_path / f"{sampling['settle']}-{sampling.get('sem_mm')}.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        truth = mr.rig.truth
        res = acquire(cfg, out, **endpoints_kwargs(mr.endpoints))
    assert (res.recorded, res.skipped) == (POSES, 0)
    s = read_session(out)
    Zi = invert(truth.Z)
    err, spreads, counts = [], [], []
    for p in s.poses:
        for got, flange_from in ((p.B, truth.X), (p.C, truth.Y)):
            want = Zi @ p.commanded @ flange_from
            err.append(np.linalg.norm(got[:3, 3] - want[:3, 3]))
        spreads.append(p.spread["marker"]["trans_mm"])
        counts.append(p.samples["B"])
    return np.asarray(err), spreads, counts


@pytest.mark.e2e
def test_a_few_samples_once_still_are_closer_to_the_truth_than_after_a_short_wait(
        mock_config, tmp_path):
    # 3 frames (50 ms) per pose: right after a move they sit on the swing's first 0.3 mm
    # crest; once still, only what is left of it (≲ 0.1 mm) and the noise (≈ 0.025 mm)
    still_err, still_spread, _ = _run(mock_config, tmp_path, {"samples": 3, **STILL})
    fixed_err, fixed_spread, _ = _run(mock_config, tmp_path, {"samples": 3, **FIXED})
    assert still_err.mean() < 0.5 * fixed_err.mean(), (still_err.mean(), fixed_err.mean())
    assert still_err.mean() < 0.08
    assert np.median(still_spread) < np.median(fixed_spread)


@pytest.mark.e2e
def test_samples_by_need_once_still_take_fewer_frames_and_record_the_noise(mock_config,
                                                                          tmp_path):
    # standard error 0.01 mm: white noise alone needs about 3·0.025²/0.01² ≈ 19 frames; a
    # swing being sampled inflates the spread and so the count
    need = {"samples": 200, "sem_mm": 0.01, "min_samples": 10}
    still_err, still_spread, still_n = _run(mock_config, tmp_path, {**need, **STILL})
    fixed_err, fixed_spread, fixed_n = _run(mock_config, tmp_path, {**need, **FIXED})
    assert np.median(still_n) < 0.7 * np.median(fixed_n), (still_n, fixed_n)
    # the still run's spreads are the tracker's noise (≈ 0.043 mm), the other's the swing too
    assert np.median(still_spread) < 0.06 < np.median(fixed_spread)
    # both meet the standard error they were asked for: their means are near the truth
    assert still_err.mean() < 0.03 and fixed_err.mean() < 0.03


@pytest.mark.e2e
def test_a_coil_that_never_settles_is_skipped_with_the_reason(mock_config, tmp_path):
    # a swing that keeps going (τ 60 s) on the real-time clock: every pose waits settle_s,
    # is tried again (a second move), then recorded as skipped naming the spread it saw
    poses = 3
    cfg_path = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                           plan={"poses": poses, "radius_mm": 20, "rotation_deg": 2},
                           sampling={"samples": 10, "settle": "still", "settle_s": 0.3},
                           mock={"clock": "real", "noise": NOISE,
                                 "settle": {**SETTLE, "tau_s": 60.0}})
    cfg = load_config(cfg_path)
    out = tmp_path / "never.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        res = acquire(cfg, out, **endpoints_kwargs(mr.endpoints))
        moves = len(mr.rig.moves)
    assert (res.recorded, res.skipped) == (0, poses)
    assert moves == 2 * poses
    for p in read_session(out).poses:
        assert p.B is None and p.C is None and p.skipped is not None
        assert p.skipped.startswith("not still after 0.3 s (marker ")
        # the swing's RMS over a 0.2 s window of a 0.3 mm, 4 Hz sine: about 0.3/√2 ≈ 0.2 mm
        spread = float(re.search(r"marker ([0-9.]+) mm RMS", p.skipped).group(1))
        assert 0.1 < spread < 0.3, p.skipped
