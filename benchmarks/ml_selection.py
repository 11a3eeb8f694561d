"""ml's distortion selection, accuracy against QR36 and speed (docs/methods.md, "The other
methods"; issue 21 item 2).

    .venv/bin/python benchmarks/ml_selection.py [--sessions 40] [--repeats 7] [--seed 0]
        [--speed-only]

Per n = 7, 20, 250 and ``--sessions`` simulated sessions (each its own random truth of Wang
et al. 2018, the Eq. 14 plan, the simulation's noise; n training poses and 200 further poses
whose probe poses are the targets):

* undistorted tracker: in how many sessions default ``ml`` (distortion "auto") chose a
  distortion model; the mean coil placement error on the targets of default ml, ml with
  distortion "none", QR36 orthonormal and QR36 raw (tmscal.calib.coil_placement_errors; with a
  distortion found, the targets undistorted as ``Calibration.placement`` does), and in how
  many sessions default ml was worse than QR36 orthonormal;
* a tracker scale of +0.1 % (``Noise(tracker_scale=1.001)``): in how many sessions default ml
  chose a distortion model, and the median scale it found.

Then the solve time at n = 500 (one session, median of ``--repeats``): QR36, ml without
distortion, default ml, in ms and as ratios to QR36 in the same run (the machine's load
moves the ms, less the ratios; the load average is printed with them). ``--speed-only``
runs only that (issue 21's goal: ml without distortion ≤ 50 ms, default ml ≤ 200 ms).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from figures import record

from tmscal.calib import coil_placement_errors, solve
from tmscal.calib.ml_model import undistort
from tmscal.sim import Noise, simulate

NS = (7, 20, 250)
N_TARGETS = 200


def placement(cal, targets: np.ndarray, truth, D: np.ndarray, raw: bool = True) -> float:
    """Mean coil placement error (mm) of a calibration on measured targets whose true pose is
    D⁻¹ applied to them (D the tracker distortion)."""
    true_targets = undistort(targets, np.linalg.inv(D), "affine")
    if raw:
        C_cmd, Y, Z = cal.placement(targets)
    else:
        C_cmd, Y, Z = targets, cal.Y, cal.Z
    return float(coil_placement_errors(true_targets, Y, Z, truth.Y, truth.Z,
                                       C_cmd=C_cmd).mean())


def sessions(n: int, count: int, scale: float, seed: int) -> dict[str, list[float]]:
    """``count`` sessions of n poses: the model default ml chose, its scale, and the coil
    placement error of each solver."""
    noise = Noise(tracker_scale=scale)
    rng = np.random.default_rng([seed, n, int(round(scale * 1e6))])
    out: dict[str, list] = {k: [] for k in ("model", "scale", "ml", "ml none", "qr36 ortho",
                                            "qr36 raw")}
    for _ in range(count):
        truth, d = simulate(n + N_TARGETS, rng, plan="eq14", noise=noise)
        A, B, C = d["A"][:n], d["marker"][:n], d["probe"][:n]
        targets = d["probe"][n:]
        D = noise.tracker_distortion
        ml = solve(A, B, C, method="ml")
        out["model"].append(ml.distortion["model"])
        out["scale"].append(ml.distortion["scale_percent"])
        out["ml"].append(placement(ml, targets, truth, D))
        out["ml none"].append(placement(solve(A, B, C, method="ml", distortion="none"),
                                        targets, truth, D))
        qr = solve(A, B, C, method="qr36")
        out["qr36 ortho"].append(placement(qr, targets, truth, D, raw=False))
        out["qr36 raw"].append(placement(qr, targets, truth, D))
    return out


def median_ms(fn, repeats: int) -> float:
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--speed-only", action="store_true", help="only the solve times at n = 500")
    a = ap.parse_args()
    t0 = time.perf_counter()
    if not a.speed_only:
        record("ml_selection", {"sessions": a.sessions})
        selection(a)
    speed(a)
    print(f"({time.perf_counter() - t0:.0f} s)")


def selection(a: argparse.Namespace) -> None:
    """The distortion chosen and the coil placement per n, without and with a tracker
    scale."""
    print(f"{a.sessions} sessions per n; Eq. 14 plan, the simulation's noise; coil placement on "
          f"{N_TARGETS} further poses' probe targets (mean, mm)")
    print(f"{'n':>4} {'distortion chosen':>18} {'ml':>8} {'ml none':>8} {'qr36 ortho':>10} "
          f"{'qr36 raw':>9} {'ml worse than qr36 ortho':>25}")
    for n in NS:
        r = sessions(n, a.sessions, 1.0, a.seed)
        chosen = sum(m != "none" for m in r["model"])
        worse = sum(x > y for x, y in zip(r["ml"], r["qr36 ortho"], strict=True))
        print(f"{n:>4} {chosen:>10}/{a.sessions:<7} {np.mean(r['ml']):>8.4f} "
              f"{np.mean(r['ml none']):>8.4f} {np.mean(r['qr36 ortho']):>10.4f} "
              f"{np.mean(r['qr36 raw']):>9.4f} {worse:>17}/{a.sessions}")
        record("ml_selection", {
            f"chosen_n{n}": chosen, f"ml_mm_n{n}": np.mean(r["ml"]),
            f"ml_none_mm_n{n}": np.mean(r["ml none"]),
            f"qr36_ortho_mm_n{n}": np.mean(r["qr36 ortho"]),
            f"qr36_raw_mm_n{n}": np.mean(r["qr36 raw"]), f"ml_worse_n{n}": worse})
    print("\ntracker scale +0.1 %:")
    print(f"{'n':>4} {'distortion chosen':>18} {'median scale %':>15} {'ml':>8} "
          f"{'qr36 raw':>9}")
    for n in NS:
        r = sessions(n, a.sessions, 1.001, a.seed)
        chosen = sum(m != "none" for m in r["model"])
        print(f"{n:>4} {chosen:>10}/{a.sessions:<7} {np.median(r['scale']):>15.3f} "
              f"{np.mean(r['ml']):>8.4f} {np.mean(r['qr36 raw']):>9.4f}")
        record("ml_selection", {
            f"scale_chosen_n{n}": chosen, f"scale_median_pct_n{n}": np.median(r["scale"]),
            f"scale_ml_mm_n{n}": np.mean(r["ml"]),
            f"scale_qr36_raw_mm_n{n}": np.mean(r["qr36 raw"])})


def speed(a: argparse.Namespace) -> None:
    """The solve times at n = 500 and their ratios to QR36, with the load average."""
    _, d = simulate(500, np.random.default_rng(a.seed), plan="eq14", noise=Noise())
    A, B, C = d["A"], d["marker"], d["probe"]
    qr = median_ms(lambda: solve(A, B, C, method="qr36"), a.repeats)
    none = median_ms(lambda: solve(A, B, C, method="ml", distortion="none"), a.repeats)
    auto = median_ms(lambda: solve(A, B, C, method="ml"), a.repeats)
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"\nsolve time at n = 500 (median of {a.repeats}; load average {load}): QR36 "
          f"{qr:.1f} ms; ml without distortion {none:.1f} ms = {none / qr:.0f} × QR36; default "
          f"ml (auto) {auto:.1f} ms = {auto / qr:.0f} × QR36")
    record("ml_selection", {"qr36_ms_n500": qr, "ml_none_ms_n500": none, "ml_auto_ms_n500": auto,
                            "ml_none_over_qr36": none / qr, "ml_auto_over_qr36": auto / qr})


if __name__ == "__main__":
    main()
