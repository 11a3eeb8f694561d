"""Force-torque self-calibration, the simulation study of Joubair et al. 2016 on serial arms and
on the paper's own MedRUE, under three error protocols (docs/selfcal.md, "Simulation study").

    .venv/bin/python benchmarks/selfcal.py [--seeds 5] [--pool 3000]
        [--arms ur5e,vs060,medrue] [--compare-seeds 2]

Per arm, protocol and seed: ``tmscal.calib.selfcal.study.simulate`` with its defaults (100
configurations by DETMAX, i.e. by O1, from the pool; ±2 mm / ±1° parameter errors; ±1 N /
±0.2 N·m wrench noise, 100 readings averaged per configuration; validation on the rest of the
pool; the identified arm's answer independent of the kept columns) with ``errors="all"``
(every length and angle in error: what a lab has), ``"seen"`` (every parameter the wrench sees,
alone or in a combination) and ``"paper"`` (exactly the kept columns, the paper's Table 1).
Printed: the number of identifiable parameters against the paper's, and the mean / max TCP
error before and after (means over seeds), raw and after a hand/eye calibration absorbs a rigid
base transform and a TCP offset, with the improvement of the mean after the hand/eye; then the
selection comparison (the paper's Table 4, errors "all", after the hand/eye) on
``--compare-seeds`` seeds. Same as ``tmscal selfcal simulate --arm A --errors E --seed S
--no-compare --trials 1``, one run at a time.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from figures import record

from tmscal.calib.selfcal.study.simulate import ERRORS, PAPER, SELECTIONS, simulate


def _mean(results: list, key: str, stat: str) -> float:
    return float(np.mean([getattr(r, key)[stat] for r in results]))


def _run(arm: str, seeds: int, pool: int) -> dict[str, list]:
    out: dict[str, list] = {}
    for errors in ERRORS:
        out[errors] = []
        for seed in range(seeds):
            print(f"  {arm} {errors} seed {seed} …", file=sys.stderr, flush=True)
            out[errors].append(simulate(arm=arm, errors=errors, pool=pool, seed=seed,
                                        compare=False, trials=1))
    return out


def _print(arm: str, runs: dict[str, list]) -> None:
    r0 = runs["all"][0]
    print(f"\n{arm}: {len(r0.identifiable)} of {r0.parameters} parameters identifiable "
          f"(the paper's MedRUE: {PAPER['identifiable']} of {PAPER['parameters']})")
    print(f"  {'errors':7s} {'raw before mean/max':>20s} {'after mean/max':>16s}"
          f" {'hand/eye before':>16s} {'after':>14s} {'gain':>6s}")
    for errors, res in runs.items():
        b, a = _mean(res, "before_absorbed", "mean_mm"), _mean(res, "after_absorbed", "mean_mm")
        print(f"  {errors:7s} {_mean(res, 'before', 'mean_mm'):10.3f} /"
              f"{_mean(res, 'before', 'max_mm'):7.2f} {_mean(res, 'after', 'mean_mm'):8.3f} /"
              f"{_mean(res, 'after', 'max_mm'):6.2f} {b:8.3f} /"
              f"{_mean(res, 'before_absorbed', 'max_mm'):6.2f} {a:6.3f} /"
              f"{_mean(res, 'after_absorbed', 'max_mm'):6.2f} {b / a:5.1f}×")
        record("selfcal", {
            f"{arm}_identifiable": len(r0.identifiable), f"{arm}_parameters": r0.parameters,
            f"{arm}_{errors}_before_mean_mm": b,
            f"{arm}_{errors}_before_max_mm": _mean(res, "before_absorbed", "max_mm"),
            f"{arm}_{errors}_after_mean_mm": a,
            f"{arm}_{errors}_after_max_mm": _mean(res, "after_absorbed", "max_mm"),
            f"{arm}_{errors}_gain": b / a,
            f"{arm}_{errors}_raw_before_mean_mm": _mean(res, "before", "mean_mm"),
            f"{arm}_{errors}_raw_before_max_mm": _mean(res, "before", "max_mm"),
            f"{arm}_{errors}_raw_after_mean_mm": _mean(res, "after", "mean_mm"),
            f"{arm}_{errors}_raw_after_max_mm": _mean(res, "after", "max_mm")})


def _print_comparison(arm: str, seeds: int, pool: int) -> None:
    print(f"\n{arm}, errors all: mean TCP error after the hand/eye (mm) by selection, {seeds} "
          "seeds × 3 noise draws (the paper's Table 4)")
    rows: dict[str, list[float]] = {s: [] for s in SELECTIONS}
    for seed in range(seeds):
        print(f"  {arm} comparison seed {seed} …", file=sys.stderr, flush=True)
        res = simulate(arm=arm, pool=pool, seed=100 + seed)
        for s in SELECTIONS:
            rows[s].append(res.indices[s]["after_absorbed"]["mean_mm"])
    fig: dict[str, float] = {}
    for s, v in sorted(rows.items(), key=lambda kv: np.mean(kv[1])):
        sd = float(np.std(v, ddof=1)) if len(v) > 1 else 0.0
        print(f"  {s:8s} {np.mean(v):7.3f} ± {sd:.3f}")
        fig.update({f"{arm}_compare_{s.lower()}_mean_mm": round(float(np.mean(v)), 3),
                    f"{arm}_compare_{s.lower()}_sd_mm": round(sd, 3)})
    record("selfcal", fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--pool", type=int, default=3000)
    ap.add_argument("--arms", default="ur5e,vs060,medrue")
    ap.add_argument("--compare-seeds", type=int, default=2)
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"command: python benchmarks/selfcal.py --seeds {args.seeds} --pool {args.pool} "
          f"--arms {args.arms} --compare-seeds {args.compare_seeds}")
    print(f"the paper (MedRUE, target workspace, errors on the kept columns): mean "
          f"{PAPER['before_mean_mm']} → {PAPER['after_mean_mm']} mm "
          f"({PAPER['before_mean_mm'] / PAPER['after_mean_mm']:.0f}×), max "
          f"{PAPER['before_max_mm']} → {PAPER['after_max_mm']} mm")
    for arm in args.arms.split(","):
        _print(arm, _run(arm, args.seeds, args.pool))
    for arm in args.arms.split(","):
        if args.compare_seeds > 0:
            _print_comparison(arm, args.compare_seeds, args.pool)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
