"""Force-torque self-calibration, the simulation study of Joubair et al. 2016 on serial arms:
the paper's protocol and the honest one side by side (docs/selfcal.md, "Simulation study").

    .venv/bin/python benchmarks/selfcal.py [--seeds 5] [--pool 3000] [--arms ur5e,vs060]
        [--compare-seeds 3]

Per arm and seed: ``tmscal.calib.selfcal.simulate`` with its defaults (100 configurations by
DETMAX, i.e. by O1, from the pool; ±2 mm / ±1° parameter errors; ±1 N / ±0.2 N·m wrench noise,
100 readings averaged per configuration; validation on the rest of the pool), once with
``errors="paper"`` (errors on the identifiable parameters only, as the paper's Table 1) and once
with ``errors="all"`` (every DH parameter in error too; the floor is the noise-free
identification). Printed: the number of identifiable parameters against the paper's, the mean
and max TCP error before and after (mean over seeds), the improvement factor of the mean, and
for "all" the floor and the share of the possible gain the identification reaches; then the
selection comparison (the paper's Table 4) on ``--compare-seeds`` seeds. Same as
``tmscal selfcal simulate [--arm A] [--errors paper|all] --seed S``, one run at a time.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from tmscal.calib.selfcal.simulate import PAPER, SELECTIONS, simulate

#: the figure the issue measured with every DH parameter in error on a UR5e (mean TCP, mm)
ISSUE_ALL = {"before_mean_mm": 11.3, "floor_mean_mm": 3.9}


def _mean(results: list, key: str, stat: str) -> float:
    return float(np.mean([getattr(r, key)[stat] for r in results]))


def _protocols(arm: str, seeds: int, pool: int) -> dict[str, list]:
    out: dict[str, list] = {}
    for errors in ("paper", "all"):
        out[errors] = []
        for seed in range(seeds):
            print(f"  {arm} {errors} seed {seed} …", file=sys.stderr, flush=True)
            out[errors].append(simulate(arm=arm, errors=errors, pool=pool, seed=seed,
                                        compare=False, trials=1))
    return out


def _print_protocols(arm: str, runs: dict[str, list]) -> None:
    r0 = runs["paper"][0]
    n_id, n_all = len(r0.identifiable), len(r0.identifiable) + len(r0.removed)
    print(f"\n{arm}: {n_id} of {n_all} parameters identifiable "
          f"(the paper's MedRUE model: {PAPER['identifiable']} of {PAPER['parameters']})")
    print(f"  {'protocol':10s} {'before mean':>11s} {'max':>7s} {'after mean':>11s} {'max':>7s}"
          f" {'gain':>6s} {'floor mean':>11s} {'reached':>8s}")
    for errors, results in runs.items():
        b, a = _mean(results, "before", "mean_mm"), _mean(results, "after", "mean_mm")
        line = (f"  {errors:10s} {b:11.3f} {_mean(results, 'before', 'max_mm'):7.3f} "
                f"{a:11.3f} {_mean(results, 'after', 'max_mm'):7.3f} {b / a:5.1f}×")
        if errors == "all":
            f = _mean(results, "floor", "mean_mm")
            line += f" {f:11.3f} {100 * (b - a) / (b - f):7.0f}%"
        print(line)


def _print_comparison(arm: str, seeds: int, pool: int) -> None:
    print(f"\n{arm}, paper protocol: mean TCP error after (mm) by selection, {seeds} seeds "
          "× 3 noise draws (the paper's Table 4)")
    rows: dict[str, list[float]] = {s: [] for s in SELECTIONS}
    for seed in range(seeds):
        print(f"  {arm} comparison seed {seed} …", file=sys.stderr, flush=True)
        res = simulate(arm=arm, pool=pool, seed=100 + seed)
        for s in SELECTIONS:
            rows[s].append(res.indices[s]["after"]["mean_mm"])
    for s, v in sorted(rows.items(), key=lambda kv: np.mean(kv[1])):
        print(f"  {s:8s} {np.mean(v):7.3f} ± {np.std(v, ddof=1) if len(v) > 1 else 0:.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--pool", type=int, default=3000)
    ap.add_argument("--arms", default="ur5e,vs060")
    ap.add_argument("--compare-seeds", type=int, default=3)
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"command: python benchmarks/selfcal.py --seeds {args.seeds} --pool {args.pool} "
          f"--arms {args.arms} --compare-seeds {args.compare_seeds}")
    print(f"the paper (MedRUE, target workspace): mean {PAPER['before_mean_mm']} → "
          f"{PAPER['after_mean_mm']} mm "
          f"({PAPER['before_mean_mm'] / PAPER['after_mean_mm']:.0f}×), max "
          f"{PAPER['before_max_mm']} → {PAPER['after_max_mm']} mm; the issue's UR5e ceiling with "
          f"every DH parameter in error: {ISSUE_ALL['before_mean_mm']} → "
          f"{ISSUE_ALL['floor_mean_mm']} mm "
          f"({ISSUE_ALL['before_mean_mm'] / ISSUE_ALL['floor_mean_mm']:.1f}×)")
    for arm in args.arms.split(","):
        _print_protocols(arm, _protocols(arm, args.seeds, args.pool))
    for arm in args.arms.split(","):
        if args.compare_seeds > 0:
            _print_comparison(arm, args.compare_seeds, args.pool)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
