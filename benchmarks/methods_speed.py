"""Solve time of the classic methods (sgo, quat, shah, li) beside QR36 and OpenCV's
calibrateRobotWorldHandEye on the same simulated poses (Eq. 14 plan, the paper's noise).

    .venv/bin/python benchmarks/methods_speed.py [--repeats 5]

Prints the median wall time per solve (ms) for the marker alone (A X = Z B, as OpenCV solves)
and for marker and probe with a shared Z. The target for SGO (Ha, Kang & Park 2016) is n = 250
in ≤ 1 s on this machine; its MATLAB implementation took 8–17 s in the Panda/Vicra comparison.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from tmscal.calib import solve
from tmscal.sim import Noise, simulate

METHODS = ["qr36", "shah", "li", "quat", "sgo"]


def median_ms(fn, repeats: int, *args, **kw) -> float:
    fn(*args, **kw)  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(*args, **kw)
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def opencv_ms(A: np.ndarray, B: np.ndarray, name: str, repeats: int) -> float:
    try:
        import cv2
    except ImportError:
        return float("nan")
    if not hasattr(cv2, "calibrateRobotWorldHandEye"):
        return float("nan")
    method = getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{name}")
    args = (list(A[:, :3, :3]), list(A[:, :3, 3:]), list(B[:, :3, :3]), list(B[:, :3, 3:]))
    return median_ms(cv2.calibrateRobotWorldHandEye, repeats, *args, method=method)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    _, d = simulate(500, np.random.default_rng(0), plan="eq14", noise=Noise())
    print(f"{'n':>4} {'bodies':>7} " + " ".join(f"{m + ' ms':>10}" for m in METHODS)
          + f" {'cv SHAH ms':>11} {'cv LI ms':>9}")
    for n in (20, 250, 500):
        A, B, C = d["A"][:n], d["marker"][:n], d["probe"][:n]
        for bodies, CC in (("marker", None), ("both", C)):
            row = []
            for m in METHODS:
                name = "qr24" if m == "qr36" and CC is None else m
                row.append(median_ms(solve, args.repeats, A, B, CC, method=name))
            cv = ([opencv_ms(A, B, "SHAH", args.repeats), opencv_ms(A, B, "LI", args.repeats)]
                  if CC is None else [float("nan")] * 2)
            print(f"{n:>4} {bodies:>7} " + " ".join(f"{t:>10.2f}" for t in row)
                  + f" {cv[0]:>11.2f} {cv[1]:>9.2f}")
    print("(marker rows: qr36 column is QR24, the marker-only linear method)")


if __name__ == "__main__":
    main()
