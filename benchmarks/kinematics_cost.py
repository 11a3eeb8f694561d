"""The kinematic estimate's cost against the number of poses (issue 30, "Linear cost";
docs/kinematics.md, "Cost"): the fit of ``tmscal solve --kinematics estimate`` (``calib.solve(A,
B, C, method="ml", kinematics="estimate", joints=q, arm="ur10")``: level auto, i.e. every level
fitted on all poses with the noise estimated, then each level on 5 folds for the held-out level
choice) on the first n poses of one simulated UR10 session, for n in ``--poses``.

    .venv/bin/python benchmarks/kinematics_cost.py [--poses 30,300,1000,10000] [--repeats 3]
                                                   [--seed 1]

The session is what ``tmscal simulate --arm ur10 --kinematic-errors realistic --poses N
--samples 10 --seed 1`` writes (the same simulation, in the process: the Eq. 14 plan, realistic
arm errors, the default noise 0.05 mm / 0.05°; any prefix of a plan is the shorter plan).
Prints per n the median over ``--repeats`` runs of the CPU seconds of the process and its wall
seconds, both as ratios to the 30-pose time of the same run, that ratio divided by n / 30
(1: linear; the fixed cost of a small fit keeps it below 1), the CPU milliseconds per pose, the
level chosen and the LM iterations of its fit; then the process's peak memory. One BLAS
thread (OPENBLAS_NUM_THREADS etc. set to 1 unless given): the figure of one core, which the
machine's other load changes less (the wall time on a shared machine is the CPU time
stretched by it; OpenBLAS's busy-waiting threads made it 4× on a busy 2-core machine).
Goals (issue 30): 1,000 poses ≤ 3 s, 10,000 ≤ 30 s, growth ≤ 1.3× linear. Takes about 3
minutes with the defaults (of which about 1 simulating the 10,000 poses).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import logging  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from figures import record  # noqa: E402

from tmscal.calib import solve  # noqa: E402
from tmscal.sim import Noise, make_arm, simulate  # noqa: E402

GOALS_S = {1000: 3.0, 10000: 30.0}
GROWTH = 1.3


def session(n: int, seed: int) -> dict[str, np.ndarray]:
    """The arrays of ``tmscal simulate --arm ur10 --kinematic-errors realistic --poses n
    --samples 10 --seed seed`` (its noise defaults): A, marker, probe (n, 4, 4) mm, joints
    (n, 6) rad."""
    rng = np.random.default_rng(seed)
    _, d = simulate(n, rng, plan="eq14", noise=Noise(0.05, 0.05, 0.05), samples=10,
                    with_probe=True, arm=make_arm("ur10", "realistic", seed))
    return d


def fit(d: dict[str, np.ndarray], n: int) -> tuple[float, float, str, int]:
    """(CPU s, wall s, level, LM iterations) of the estimate on the first n poses."""
    c0, w0 = time.process_time(), time.perf_counter()
    cal = solve(d["A"][:n], d["marker"][:n], d["probe"][:n], method="ml",
                kinematics="estimate", joints=d["joints"][:n], arm="ur10")
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    return cpu, wall, str(cal.extra["kinematics"]), int(cal.extra["iterations"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--poses", type=lambda s: [int(x) for x in s.split(",")],
                    default=[30, 300, 1000, 10000], help="pose counts; the first is the base")
    ap.add_argument("--repeats", type=int, default=3, help="runs per pose count (median)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    ns = args.poses
    t0 = time.perf_counter()
    d = session(max(ns), args.seed)
    print(f"## Cost of the kinematic estimate (level auto, noise estimated, 5 folds) on the "
          f"first n poses of a simulated UR10 session (seed {args.seed}, "
          f"{max(ns)} poses simulated in {time.perf_counter() - t0:.0f} s); median of "
          f"{args.repeats} runs, one BLAS thread (OPENBLAS_NUM_THREADS="
          f"{os.environ.get('OPENBLAS_NUM_THREADS')})\n")
    fit(d, ns[0])  # warm-up: imports and caches out of the first figure
    rows = {}
    for n in ns:
        runs = [fit(d, n) for _ in range(args.repeats)]
        rows[n] = (float(np.median([r[0] for r in runs])),
                   float(np.median([r[1] for r in runs])), runs[-1][2], runs[-1][3])
    base_c, base_w = rows[ns[0]][0], rows[ns[0]][1]
    print(f"  {'poses':>6}{'CPU s':>9}{'wall s':>9}{'CPU ratio':>11}{'wall ratio':>12}"
          f"{'÷ linear':>10}{'ms/pose':>9}{'level':>9}{'LM its':>8}")
    figs: dict[str, float] = {}
    for n, (c, w, level, its) in rows.items():
        rc, rw = c / base_c, w / base_w
        lin = rc / (n / ns[0])
        print(f"  {n:>6}{c:>9.2f}{w:>9.2f}{rc:>11.1f}{rw:>12.1f}{lin:>10.2f}"
              f"{1e3 * c / n:>9.2f}{level:>9}{its:>8}")
        figs |= {f"cpu_s_n{n}": round(c, 2), f"wall_s_n{n}": round(w, 2),
                 f"cpu_ratio_n{n}": round(rc, 1), f"wall_ratio_n{n}": round(rw, 1),
                 f"over_linear_n{n}": round(lin, 2), f"ms_per_pose_n{n}": round(1e3 * c / n, 2)}
    big = [n for n in ns if n >= 1000]
    if len(big) >= 2:  # the growth where the fixed cost no longer hides it
        a, b = big[0], big[-1]
        g = (rows[b][0] / rows[a][0]) / (b / a)
        print(f"\n  {a} → {b} poses: CPU × {rows[b][0] / rows[a][0]:.1f} for × {b / a:g} poses "
              f"= {g:.2f} × linear (goal ≤ {GROWTH})")
        figs[f"growth_n{a}_n{b}"] = round(g, 2)
    for n, goal in GOALS_S.items():
        if n in rows:
            print(f"  {n} poses: {rows[n][0]:.2f} s CPU, {rows[n][1]:.2f} s wall (goal ≤ "
                  f"{goal:g} s)")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    print(f"  peak memory of the process: {peak:.0f} MB")
    figs["peak_mb"] = round(peak)
    record("kinematics_cost", figs)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
