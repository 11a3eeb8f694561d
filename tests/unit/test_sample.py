"""sample_pose averages: the recorded pose's scatter shrinks as 1/√n with the sample count.

A small in-test tracker (a subclass of the driver contract) returns frames with Gaussian noise
of known sigma around known poses, and the in-process sim robot (``tmscal.drivers.sim``) stands
still at the sim rig's P0 and reports it with read jitter of known sigma
(``read_trans_sigma_mm``); over many seeded repetitions the standard deviation of the averaged
pose's error must match sigma/√n. Recording the first sample instead of the mean (or any
estimator that does not average) fails these checks.

The tracker stays a fake: its noise is Gaussian on the pose itself, so sigma/√n is exact; the
sim tracker's noise is on the tool's fiducials, through Horn's fit, with no closed-form sigma.
"""

from __future__ import annotations

import numpy as np
import pytest

from tmscal.acquisition.sample import sample_pose
from tmscal.config import SamplingConfig
from tmscal.drivers.base import ToolState, Tracker, TrackerFrame
from tmscal.drivers.sim.robot import SimRobot
from tmscal.geometry import make_pose, matrix_from_rotvec, random_rotation, rotvec_from_matrix
from tmscal.sim import TMS_RIG_P0

SIGMA_T_MM = 0.25      # per-axis translation noise of a tracked tool
SIGMA_R_RAD = 1e-3     # per-axis rotation noise of a tracked tool (rotation vector)
SIGMA_A_MM = 0.05      # per-axis translation noise of the robot's reported flange pose
REPS = 300             # repetitions per sample count
_RNG0 = np.random.default_rng(20240611)
TRUE = {"marker": make_pose(random_rotation(_RNG0), [120.0, -40.0, 1500.0]),
        "probe": make_pose(random_rotation(_RNG0), [80.0, 10.0, 1480.0])}
TRUE_A = TMS_RIG_P0      # where the sim robot stands (base_from_flange, mm)


def _noisy(T: np.ndarray, rng: np.random.Generator, s_t: float, s_r: float) -> np.ndarray:
    R = T[:3, :3] @ matrix_from_rotvec(rng.normal(0.0, s_r, 3)) if s_r else T[:3, :3]
    return make_pose(R, T[:3, 3] + rng.normal(0.0, s_t, 3))


class NoisyTracker(Tracker):
    """A new frame on every read: each tool at its true pose plus Gaussian noise."""

    name = "noisy-test-tracker"

    def __init__(self, rng: np.random.Generator) -> None:
        # a slow nominal rate only makes sample_pose's wall-time limit generous
        super().__init__(["marker", "probe"], frame_rate_hz=1.0)
        self.rng = rng
        self.frame = 0

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _read(self) -> TrackerFrame:
        self.frame += 1
        tools = {b: ToolState(pose=_noisy(T, self.rng, SIGMA_T_MM, SIGMA_R_RAD))
                 for b, T in TRUE.items()}
        return TrackerFrame(frame=self.frame, host_time=0.0, tools=tools)


def _robot(seed: int) -> SimRobot:
    """The sim robot at TRUE_A: no positioning error, every read jittered by N(0, SIGMA_A_MM)
    mm per axis (its rig's own, seeded random numbers)."""
    return SimRobot(channel=f"test-sample-{seed}", seed=seed, rot_sigma_deg=0.0,
                    trans_sigma_mm=0.0, read_trans_sigma_mm=SIGMA_A_MM)


def _errors(n: int, seed: int) -> dict[str, np.ndarray]:
    """Over REPS seeded runs of sample_pose with n samples: per-axis translation errors (mm)
    of the averaged marker, probe and A, rotation-vector errors (rad) of the averaged marker,
    the recorded A counts, and the recorded marker spreads (mm)."""
    rng = np.random.default_rng(seed)
    tr, rob = NoisyTracker(rng).open(), _robot(seed).open()
    out: dict[str, list] = {"marker": [], "probe": [], "A": [], "rot": [], "nA": [],
                            "spread": []}
    for _ in range(REPS):
        s = sample_pose(rob, tr, SamplingConfig(samples=n, settle_s=0.0), sleep=lambda _s: None)
        assert s.problem is None and s.samples["marker"] == n and s.samples["probe"] == n
        for b in ("marker", "probe"):
            out[b].append(s.bodies[b][:3, 3] - TRUE[b][:3, 3])
        out["A"].append(s.A[:3, 3] - TRUE_A[:3, 3])
        out["rot"].append(rotvec_from_matrix(TRUE["marker"][:3, :3].T @ s.bodies["marker"][:3, :3]))
        out["nA"].append(s.samples["A"])
        out["spread"].append(s.spread["marker"]["trans_mm"])
    rob.close()
    return {k: np.asarray(v) for k, v in out.items()}


@pytest.fixture(scope="module")
def runs() -> dict[int, dict[str, np.ndarray]]:
    return {n: _errors(n, seed=n) for n in (4, 16, 64)}


def _sd(e: np.ndarray) -> float:
    """SD of zero-mean errors pooled over the axes (the truth is known, so no mean is
    subtracted): an estimate from 3·REPS values, relative standard error ≈ 1/√(6·REPS) ≈ 2.4%."""
    return float(np.sqrt(np.mean(e ** 2)))


# 4.5 relative standard errors: seeded, so this is a fixed margin, not a flaky one
_TOL = 4.5 / np.sqrt(6 * REPS)


@pytest.mark.parametrize("n", [4, 16, 64])
@pytest.mark.parametrize("body", ["marker", "probe"])
def test_tool_translation_scatter_is_sigma_over_root_n(runs, n, body):
    sd = _sd(runs[n][body])
    want = SIGMA_T_MM / np.sqrt(n)
    assert abs(sd / want - 1) < _TOL, f"{body}, n={n}: SD {sd:.4f} mm, want {want:.4f} mm"


@pytest.mark.parametrize("n", [4, 16, 64])
def test_tool_rotation_scatter_is_sigma_over_root_n(runs, n):
    sd = _sd(runs[n]["rot"])
    want = SIGMA_R_RAD / np.sqrt(n)
    assert abs(sd / want - 1) < _TOL, f"n={n}: SD {sd:.2e} rad, want {want:.2e} rad"


@pytest.mark.parametrize("n", [4, 16, 64])
def test_robot_pose_is_averaged_over_its_reads(runs, n):
    k = runs[n]["nA"]
    assert (k == k[0]).all() and k[0] >= min(n, 10)
    sd = _sd(runs[n]["A"])
    want = SIGMA_A_MM / np.sqrt(k[0])
    assert abs(sd / want - 1) < _TOL, f"n={n}: A SD {sd:.4f} mm from {k[0]} reads, want {want:.4f}"


def test_more_samples_are_clearly_better(runs):
    # 1/√n predicts a factor 4 between n = 4 and n = 64; a single-sample pose gives 1
    for body in ("marker", "probe"):
        assert _sd(runs[64][body]) < 0.3 * _sd(runs[4][body])
    assert _sd(runs[64]["rot"]) < 0.3 * _sd(runs[4]["rot"])


@pytest.mark.parametrize("n", [4, 16, 64])
def test_reported_spread_is_the_sample_scatter(runs, n):
    # RMS distance of n samples from their mean: E[d²] = 3σ²(n − 1)/n
    ms = float(np.mean(runs[n]["spread"] ** 2))
    want = 3 * SIGMA_T_MM ** 2 * (n - 1) / n
    assert abs(ms / want - 1) < 0.1, f"n={n}: mean spread² {ms:.4f}, want {want:.4f}"


# --- samples by need -------------------------------------------------------------------------

@pytest.mark.parametrize("sem", [0.1, 0.05])
def test_samples_by_need_reach_the_standard_error_they_were_asked_for(sem):
    # with sem_mm the count is the first k at which spread/√k ≤ sem_mm: about 3σ²/sem²
    # frames (19 and 75 here), and the averaged pose's 3D error then has an RMS of about
    # sem_mm over REPS seeded runs (relative SE ≈ 1/√(2·3·REPS) ≈ 2.4 %; stopping when the
    # sample spread happens to be low adds a little: the margin is 12 %)
    rng = np.random.default_rng(int(1000 * sem))
    tr, rob = NoisyTracker(rng).open(), _robot(int(1000 * sem)).open()
    err, counts = [], []
    for _ in range(REPS):
        s = sample_pose(rob, tr, SamplingConfig(samples=1000, settle_s=0.0, sem_mm=sem,
                                                min_samples=10), sleep=lambda _s: None)
        assert s.problem is None and s.samples["marker"] == s.frames < 1000
        err.append(np.linalg.norm(s.bodies["marker"][:3, 3] - TRUE["marker"][:3, 3]))
        counts.append(s.frames)
    rob.close()
    rms = float(np.sqrt(np.mean(np.square(err))))
    assert abs(rms / sem - 1) < 0.12, f"RMS error {rms:.4f} mm for sem_mm {sem}"
    want = 3 * SIGMA_T_MM ** 2 / sem ** 2
    assert abs(np.mean(counts) / want - 1) < 0.15, f"{np.mean(counts):.1f} frames, ~{want:.0f}"
