"""Why ml's estimated-arm placement stays about 1.5× the true arm's (docs/kinematics.md, "What
it says"; issue 20): the ratio against the number of poses, on simulated data.

    .venv/bin/python benchmarks/kinematics_ratio.py [--seeds 4] [--poses 40,80,160]

Per seed: a UR5e whose every DH deviation (θ0, d, a, α per joint, β on the parallel axes) is
drawn N(0, σ²) with the mock's realistic sizes (0.34 mm, 0.03°; docs/kinematics.md,
"Realistic arm errors"), random X and Z, a coil 150 mm below the flange, joints uniform within
±0.3 rad of the home; each pose's flange error is the mock's robot noise (0.05 mm per
component, 0.029° per axis of the rotation vector), each tracked pose's error 0.01 mm and
0.02° (100 averaged frames). ml with the arm estimated (``kinematics="estimate"``, level
full) and ml on the TRUE arm's flange poses (the ceiling) are solved on n poses; the error is
the mean distance, over 100 further configurations, between the coil position each
calibration predicts in the tracker frame (Z⁻¹ A(q) Y) and the truth. Printed per n: both
errors (mm, mean over the seeds) and their ratio. If the ratio came from too few poses it
would fall with n; it stays, since both errors shrink as 1/√n and the estimated arm has about
twice the parameters (X, Y, Z and some 18 identified combinations of the arm against X, Y, Z
alone). Takes about a minute.
"""

from __future__ import annotations

import argparse
import logging

import numpy as np
from figures import record

from tmscal.calib import solve
from tmscal.calib.kinematics import arm_by_name, base_from_flange
from tmscal.calib.kinematics.levels import Tolerances, level_parameters, prior_sigmas
from tmscal.geometry import make_pose, matrix_from_rotvec, random_rotation

HOME = np.array([np.pi, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])


def _perturbed(P: np.ndarray, rng: np.random.Generator, deg: float, mm: float) -> np.ndarray:
    """P · exp(ε): rotation vector N(0, deg²) per axis, offset N(0, mm²) per component."""
    E = np.tile(np.eye(4), (len(P), 1, 1))
    E[:, :3, :3] = matrix_from_rotvec(rng.normal(0, np.radians(deg), (len(P), 3)))
    E[:, :3, 3] = rng.normal(0, mm, (len(P), 3))
    return P @ E


def one(seed: int, n: int) -> tuple[float, float]:
    """(estimated arm's, true arm's) mean coil position error (mm) of one simulated rig."""
    rng = np.random.default_rng(100 + seed)
    arm0 = arm_by_name("ur5e")
    names = level_parameters(arm0, "full")
    true = arm0.with_deviations(names, rng.normal(0, 1, len(names))
                                * prior_sigmas(names, Tolerances(0.34, 0.03)))
    X = make_pose(random_rotation(rng), rng.uniform(-50, 50, 3))
    Y = make_pose(np.eye(3), [0.0, 0.0, 150.0])
    Z = make_pose(random_rotation(rng), rng.uniform(500, 1500, 3))
    q = HOME + rng.uniform(-0.3, 0.3, (n, 6))
    At = _perturbed(base_from_flange(true, q), rng, 0.029, 0.05)
    B = _perturbed(np.linalg.inv(Z) @ At @ X, rng, 0.02, 0.01)
    C = _perturbed(np.linalg.inv(Z) @ At @ Y, rng, 0.02, 0.01)
    est = solve(base_from_flange(arm0, q), B, C, method="ml", joints=q, arm=arm0,
                kinematics="estimate", level="full")
    ceiling = solve(base_from_flange(true, q), B, C, method="ml", distortion="none")
    qt = HOME + rng.uniform(-0.3, 0.3, (100, 6))
    truth = (np.linalg.inv(Z) @ base_from_flange(true, qt) @ Y)[:, :3, 3]
    # the estimate's controller frame is the identity here (A is the nominal arm's own)
    pe = (np.linalg.inv(est.Z) @ base_from_flange(est.arm.arm, qt) @ est.Y)[:, :3, 3]
    pt = (np.linalg.inv(ceiling.Z) @ base_from_flange(true, qt) @ ceiling.Y)[:, :3, 3]
    return (float(np.linalg.norm(pe - truth, axis=1).mean()),
            float(np.linalg.norm(pt - truth, axis=1).mean()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--poses", type=lambda s: [int(x) for x in s.split(",")],
                    default=[40, 80, 160])
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    print(f"## ml with the estimated arm against ml on the true arm (simulated UR5e, "
          f"{args.seeds} seeds; mean coil position error mm over 100 configurations)\n")
    print(f"  {'poses':>6}{'estimated arm':>16}{'true arm':>12}{'estimated / true':>19}")
    for n in args.poses:
        e, t = np.mean([one(s, n) for s in range(args.seeds)], axis=0)
        print(f"  {n:>6}{e:>16.4f}{t:>12.4f}{e / t:>19.2f}", flush=True)
        record("kinematics_ratio", {f"n{n}_estimated_mm": e, f"n{n}_true_mm": t,
                                    f"n{n}_ratio": e / t})


if __name__ == "__main__":
    main()
