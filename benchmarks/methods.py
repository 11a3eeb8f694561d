"""Every registered method on the simulated protocol of Wang et al. (2018) with the Eq. 14 plan
(500 poses; train on the first n = 7, 14, 20, 50, 250; test on poses 251–500), over several
random rigs, beside OpenCV's SHAH and LI (cv2.calibrateRobotWorldHandEye, opencv 4.x; run on
the marker and on the probe separately, as QR24 is) on the same poses; then the same with a
tracker scale error of +0.1 % (the sim rig's tracker distortion).

    .venv/bin/python benchmarks/methods.py [--seeds 5] [--methods qr24,qr36,…]

Per method and n (mean over the seeds; time: median):
  coil     the coil placement error on the test poses' probe targets, mm (docs/methods.md;
           with a tracker distortion, against where each measured target really is)
  Y        ‖t(Ŷ) − t(Y)‖, the ground-truth error of Y's translation, mm
  e_t      the held-out error on the test poses, mm (marker + probe, + e_z for QR24)
  bound    the Cramér–Rao bound of Y's RMS translation error, mm (when tmscal.calib.bound is
           there; the same for every method)
  ms       solve time
Runs with whatever is registered in tmscal.calib.METHODS. Records what it prints in
benchmarks/out/methods.json (``benchmarks/figures.py``; with the scale, names start
``scale0_1_``).
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np
from figures import record

from tmscal import calib
from tmscal.calib import coil_placement_errors, solve, truth_errors
from tmscal.calib.ml_model import undistort
from tmscal.errors import CalibrationError
from tmscal.geometry import make_pose
from tmscal.sim import TOOL_8700340_MM, Noise, simulate

NS = (7, 14, 20, 50, 250)
N_POSES, N_TEST_FROM = 500, 250


def opencv_solver(name: str) -> Callable[..., tuple[np.ndarray, np.ndarray]] | None:
    """OpenCV's robot-world/hand-eye solver ``name`` (SHAH, LI) as fn(A, N) -> (W, Z), or
    None without opencv 4.x."""
    try:
        import cv2
    except ImportError:
        return None
    if not hasattr(cv2, "calibrateRobotWorldHandEye"):
        return None
    flag = getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{name}")

    def run(A: np.ndarray, N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R1, t1, R2, t2 = cv2.calibrateRobotWorldHandEye(
            list(A[:, :3, :3]), list(A[:, :3, 3:]), list(N[:, :3, :3]), list(N[:, :3, 3:]),
            method=flag)
        return make_pose(R1, t1[:, 0]), make_pose(R2, t2[:, 0])
    return run


def _bound_fn() -> Callable[..., float] | None:
    """Y's RMS translation bound for poses A, the truth and the default sim noise, or None."""
    try:
        from tmscal.calib import bound
    except ImportError:
        return None
    noise = Noise()
    opts = bound.sim_noise_options(noise.fiducial_sigma_mm, noise.robot_rot_sigma_deg,
                                   noise.robot_trans_sigma_mm, TOOL_8700340_MM)

    def fn(A: np.ndarray, B: np.ndarray, C: np.ndarray, truth: dict[str, Any]) -> float:
        return bound.translation_rms_bound(bound.crb(A, B, C, truth, opts), "Y", 2)
    return fn


def _figures(C: np.ndarray, Y: np.ndarray, Z: np.ndarray, truth: dict[str, np.ndarray],
             e_t: float, dt: float, C_cmd: np.ndarray | None = None) -> dict[str, float]:
    """The coil placement error: the robot is told to put the coil at the measured target C
    (A = (Ẑ C_cmd Ŷ⁻¹)⊥, C_cmd = C undistorted by a solver that found a distortion); it
    lands at A Y, where the target really is at Z D⁻¹ C (D: the tracker distortion; without
    one this is ``calib.coil_placement_errors``)."""
    C_true = undistort(C, np.linalg.inv(truth["D"]), "affine")
    coil = coil_placement_errors(C_true, Y, Z, truth["Y"], truth["Z"],
                                 C_cmd=C if C_cmd is None else C_cmd)
    te = truth_errors({"Y": Y}, {"Y": truth["Y"]})
    return {"coil": float(coil.mean()), "Y": te["Y"]["trans_mm"], "e_t": e_t, "ms": 1e3 * dt}


def run_ours(m: str, d: dict[str, np.ndarray], n: int, truth: dict[str, np.ndarray]
             ) -> dict[str, float]:
    A, B, C = d["A"], d["marker"], d["probe"]
    opts = ({"handheld_B": B[0], "handheld_C": C[0]} if m == "handheld" else {})
    t0 = time.perf_counter()
    cal = solve(A[:n], B[:n], C[:n], method=m, **opts)
    dt = time.perf_counter() - t0
    sl = slice(N_TEST_FROM, None)
    e_t = cal.errors(A[sl], B[sl], C[sl])["e_t_mm"]
    C_cmd, Y, Z = cal.placement(C[sl])  # QR24: the marker's Z, as tmscal solve does
    return _figures(C[sl], Y, Z, truth, e_t, dt, C_cmd=C_cmd)


def run_opencv(fn: Callable[..., Any], d: dict[str, np.ndarray], n: int,
               truth: dict[str, np.ndarray]) -> dict[str, float]:
    """OpenCV on the marker and on the probe separately (two Z, as QR24)."""
    from tmscal.calib.metrics import holdout_errors

    A, B, C = d["A"], d["marker"], d["probe"]
    t0 = time.perf_counter()
    X, ZM = fn(A[:n], B[:n])
    Y, ZP = fn(A[:n], C[:n])
    dt = time.perf_counter() - t0
    sl = slice(N_TEST_FROM, None)
    e_t = holdout_errors(A[sl], {"marker": B[sl], "probe": C[sl]}, {"marker": X, "probe": Y},
                         {"marker": ZM, "probe": ZP})["e_t_mm"]
    return _figures(C[sl], Y, ZM, truth, e_t, dt)  # the marker's Z, as for QR24


def table(methods: list[str], seeds: int, scale: float) -> None:
    cv = {f"cv{k}": opencv_solver(k) for k in ("SHAH", "LI")}
    cv = {k: v for k, v in cv.items() if v is not None}
    bound_fn = _bound_fn()
    rows: dict[tuple[str, int], dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    bounds: dict[int, list[float]] = defaultdict(list)
    for s in range(seeds):
        noise = Noise(tracker_scale=scale)
        truth_obj, d = simulate(N_POSES, np.random.default_rng(100 + s), plan="eq14",
                                noise=noise)
        truth = {"X": truth_obj.X, "Y": truth_obj.Y, "Z": truth_obj.Z}
        bound_truth = dict(truth)
        truth["D"] = noise.tracker_distortion
        for n in NS:
            if bound_fn is not None:
                bounds[n].append(bound_fn(d["A"][:n], d["marker"][:n], d["probe"][:n],
                                         bound_truth))
            for m in methods + list(cv):
                try:
                    r = run_opencv(cv[m], d, n, truth) if m in cv else run_ours(m, d, n, truth)
                except CalibrationError as e:
                    r = {"failed": 1.0}
                    print(f"  ({m}, n = {n}, seed {s}: {e})")
                for k, v in r.items():
                    rows[(m, n)][k].append(v)
    print(f"\ntracker scale {scale:g} ({(scale - 1) * 100:+.2f} %), {seeds} rigs, Eq. 14 plan, "
          f"train on poses 1…n, test on {N_POSES - N_TEST_FROM} poses after {N_TEST_FROM}")
    print(f"{'n':>4} {'method':<9}{'coil mm':>10}{'Y mm':>10}{'e_t mm':>10}{'bound mm':>10}"
          f"{'Y/bound':>9}{'ms':>10}")
    pre = "" if scale == 1.0 else f"scale{(scale - 1) * 100:g}_".replace(".", "_")
    figures: dict[str, float | None] = {}
    for n in NS:
        b = float(np.mean(bounds[n])) if bounds[n] else float("nan")
        figures[f"{pre}bound_mm_n{n}"] = round(b, 4) if bounds[n] else None
        for m in methods + list(cv):
            r = rows[(m, n)]
            if "coil" not in r:
                print(f"{n:>4} {m:<9}  (failed)")
                continue
            y = float(np.mean(r["Y"]))
            print(f"{n:>4} {m:<9}{np.mean(r['coil']):>10.4f}{y:>10.4f}{np.mean(r['e_t']):>10.4f}"
                  f"{b:>10.4f}{y / b:>9.2f}{np.median(r['ms']):>10.2f}")
            figures.update({f"{pre}{m}_coil_mm_n{n}": round(float(np.mean(r["coil"])), 4),
                            f"{pre}{m}_y_mm_n{n}": round(y, 4),
                            f"{pre}{m}_e_t_mm_n{n}": round(float(np.mean(r["e_t"])), 4),
                            f"{pre}{m}_ms_n{n}": round(float(np.median(r["ms"])), 2)})
        print()
    record("methods", figures)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--methods", default=None,
                    help="comma-separated (default: every registered method)")
    args = ap.parse_args()
    methods = (list(calib.METHODS) if args.methods is None
               else [m.strip() for m in args.methods.split(",")])
    print(f"methods: {', '.join(methods)}; OpenCV: "
          f"{'SHAH, LI' if opencv_solver('SHAH') else 'not available (opencv-python<5)'}; "
          f"bound: {'yes' if _bound_fn() else 'no (tmscal.calib.bound missing)'}")
    t0 = time.perf_counter()
    for scale in (1.0, 1.001):
        table(methods, args.seeds, scale)
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
