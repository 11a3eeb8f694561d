"""The size of the mock rig's realistic arm errors (``mock.kinematics.errors: realistic``;
docs/kinematics.md, "Realistic arm errors"): the flange position error they give over the
mock's workspace, to check the assumption against a published order of magnitude (Nubiola and
Bonev 2013: 0.968 mm mean position error of an uncalibrated ABB IRB 1600).

    .venv/bin/python benchmarks/realistic_arm_errors.py [--arms ur5e,vs060] [--seeds 50]

For each arm and each seed (``make_arm(arm, "realistic", seed)``: one draw of the true arm),
the 60 poses of an Eq. 14 plan (Wang et al. 2018: ±100 mm, ±10°) around the mock's start pose
P0 (flange at (500, 0, 400) mm in the rig frame, tool down; the arm at its registry mount),
joints by inverse kinematics on the NOMINAL model as the mock controller does (a pose out of
reach is left out). Per pose:

* **raw**: the distance (mm) between where the flange really is (the true arm at those joints)
  and where the controller reports it (the nominal arm): the arm's absolute error, base and
  flange errors included;
* **fitted**: the same after the best rigid base and flange transforms, fitted by least
  squares to all the arm's poses of that draw (the flange origin and a point 100 mm out along
  the flange's z): what a robot/world and hand/eye calibration cannot absorb, i.e. the part
  only a kinematic calibration removes;
* **fitted, whole range**: the fitted error over ``SPREAD`` joint configurations drawn
  uniformly within the joint limits instead (the whole workspace, as Nubiola and Bonev
  measured over theirs, with base and tool frames identified).

Prints per arm σ_L (mm), the mean, median and 95th percentile of the raw error and the means
of the fitted ones, over seeds × poses. A few seconds per arm and 10 seeds.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.optimize import least_squares

from tmscal.calib.kinematics import ARM_NAMES
from tmscal.geometry import make_pose, matrix_from_rotvec
from tmscal.poses import eq14_poses
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, make_arm, tms_rig_truth
from tmscal.sim.arm import realistic_sigmas

#: the plan of the mock's workspace: seed, size
PLAN_SEED, PLAN_POSES = 1, 60
#: the second point of the rigid fit, along the flange's z (mm)
TOOL_MM = 100.0
#: joint configurations per draw over the whole joint range
SPREAD = 200


def _points(T: np.ndarray) -> np.ndarray:
    """(m, 2, 3): the flange origin and the point ``TOOL_MM`` along its z, of poses T."""
    return np.stack([T[:, :3, 3], T[:, :3, 3] + TOOL_MM * T[:, :3, 2]], axis=1)


def _fitted(reported: np.ndarray, actual: np.ndarray) -> np.ndarray:
    """Per pose the flange origin's distance (mm) between ``actual`` and Zc · reported · Xc,
    with the rigid Zc, Xc fitted by least squares to both points of every pose."""
    target = _points(actual)

    def pose(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (make_pose(matrix_from_rotvec(p[:3]), p[3:6]),
                make_pose(matrix_from_rotvec(p[6:9]), p[9:12]))

    def residual(p: np.ndarray) -> np.ndarray:
        Zc, Xc = pose(p)
        return (_points(Zc @ reported @ Xc) - target).ravel()

    Zc, Xc = pose(least_squares(residual, np.zeros(12)).x)
    return np.linalg.norm((Zc @ reported @ Xc)[:, :3, 3] - actual[:, :3, 3], axis=1)


def measure(arm: str, seeds: int) -> dict[str, float]:
    """The raw and fitted flange errors (mm) of ``seeds`` realistic draws of ``arm``."""
    plan = eq14_poses(TMS_RIG_P0, PLAN_POSES, np.random.default_rng(PLAN_SEED))
    raw: list[np.ndarray] = []
    fitted: list[np.ndarray] = []
    whole: list[np.ndarray] = []
    for seed in range(seeds):
        pair = make_arm(arm, "realistic", seed)
        rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0, arm=pair)
        qs = [q for q in (rig.reach(P) for P in plan) if q is not None]
        rep = np.stack([pair.reported(q) for q in qs])
        act = np.stack([pair.actual(q) for q in qs])
        raw.append(np.linalg.norm(act[:, :3, 3] - rep[:, :3, 3], axis=1))
        fitted.append(_fitted(rep, act))
        lim = pair.nominal.joint_limits_rad
        Q = np.random.default_rng([seed, 1]).uniform(lim[:, 0], lim[:, 1],
                                                     (SPREAD, len(lim)))
        whole.append(_fitted(pair.reported(Q), pair.actual(Q)))
    r, f = np.concatenate(raw), np.concatenate(fitted)
    return {"sigma_l_mm": realistic_sigmas(arm)[0], "raw_mean": float(r.mean()),
            "raw_median": float(np.median(r)), "raw_p95": float(np.percentile(r, 95)),
            "fitted_mean": float(f.mean()), "whole_mean": float(np.concatenate(whole).mean()),
            "poses": len(r)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--arms", default=",".join(ARM_NAMES),
                    help="comma-separated registered arms (default: all)")
    ap.add_argument("--seeds", type=int, default=50, help="draws of the true arm per arm")
    args = ap.parse_args()
    print(f"realistic arm errors over an Eq. 14 plan ({PLAN_POSES} poses, ±100 mm, ±10°) "
          f"around the mock P0, {args.seeds} draws per arm; flange position error, mm")
    print(f"{'arm':8} {'σ_L':>6} {'raw mean':>9} {'median':>7} {'95 %':>6} {'fitted':>7} "
          f"{'fitted, whole range':>20}")
    for arm in args.arms.split(","):
        m = measure(arm.strip(), args.seeds)
        print(f"{arm:8} {m['sigma_l_mm']:6.3f} {m['raw_mean']:9.3f} {m['raw_median']:7.3f} "
              f"{m['raw_p95']:6.3f} {m['fitted_mean']:7.3f} {m['whole_mean']:20.3f}")


if __name__ == "__main__":
    main()
