"""Solve time of QR24 / QR36 at n = 20, 250, 500 poses, beside OpenCV's SHAH and LI
(cv2.calibrateRobotWorldHandEye, opencv 4.x) on the same poses, measured in the same run.

    .venv/bin/python benchmarks/speed.py [--repeats 30]

Prints median wall time per solve (ms) and the ratio OpenCV / ours. QR24 solves the marker
only (A X = Z B), as OpenCV does; QR36 solves marker and probe jointly.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from figures import record

from tmscal.calib import solve
from tmscal.sim import Noise, simulate


def median_ms(fn, repeats: int, *args) -> float:
    fn(*args)  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(*args)
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def opencv_solver(method_name: str):
    try:
        import cv2
    except ImportError:
        return None
    if not hasattr(cv2, "calibrateRobotWorldHandEye"):
        return None
    method = getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{method_name}")

    def run(A, B):
        # OpenCV solves cTw·wTb = cTg·gTb: A as world2cam, B as base2gripper
        return cv2.calibrateRobotWorldHandEye(
            list(A[:, :3, :3]), list(A[:, :3, 3:]), list(B[:, :3, :3]), list(B[:, :3, 3:]),
            method=method)
    return run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=30)
    args = ap.parse_args()
    _, d = simulate(500, np.random.default_rng(0), plan="eq14", noise=Noise())
    figures: dict[str, float] = {}
    shah, li = opencv_solver("SHAH"), opencv_solver("LI")
    print(f"{'n':>5} {'QR24 ms':>9} {'QR36 ms':>9} {'SHAH ms':>9} {'LI ms':>9} "
          f"{'LI/QR36':>8} {'LI/QR24':>8} {'SHAH/QR36':>10}")
    for n in (20, 250, 500):
        A, B, C = d["A"][:n], d["marker"][:n], d["probe"][:n]
        t24 = median_ms(solve, args.repeats, A, B, None, "qr24")
        t36 = median_ms(solve, args.repeats, A, B, C, "qr36")
        ts = median_ms(shah, args.repeats, A, B) if shah else float("nan")
        tl = median_ms(li, args.repeats, A, B) if li else float("nan")
        print(f"{n:>5} {t24:>9.3f} {t36:>9.3f} {ts:>9.3f} {tl:>9.3f} {tl / t36:>8.1f} "
              f"{tl / t24:>8.1f} {ts / t36:>10.1f}")
        figures.update({f"qr24_ms_n{n}": t24, f"qr36_ms_n{n}": t36, f"shah_ms_n{n}": ts,
                        f"li_ms_n{n}": tl, f"li_over_qr36_n{n}": tl / t36})
    record("speed", figures)
    if shah is None:
        print("(cv2.calibrateRobotWorldHandEye not available: install opencv-python-headless<5)")


if __name__ == "__main__":
    main()
