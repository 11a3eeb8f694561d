"""The ml solver against the Cramér–Rao bound, and the coverage of its predicted uncertainty.

    .venv/bin/python benchmarks/ml_bound.py [--n 20] [--sessions 200] [--distortion none]

For one simulated rig (Wang et al. 2018's random truth, Eq. 14 plan, the simulation's noise),
``--sessions`` independent sessions of n poses: the RMS error of Ŷ's translation for ml and
for QR36 (orthonormal) divided by the Cramér–Rao bound of the same linearised model
(``tmscal.calib.bound``, on each session's poses, RMS over sessions); the share of sessions whose
true coil-centre error is inside ml's predicted 95 % interval; the mean coil placement error on
200 further poses of each session for ml and QR36 (raw and orthonormal); ml's median solve
time. See docs/methods.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from figures import record

from tmscal.calib import coil_placement_errors, solve
from tmscal.calib.bound import crb, sim_noise_options, translation_rms_bound
from tmscal.sim import TOOL_8700340_MM, Noise, Truth, simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20, help="poses per session")
    ap.add_argument("--sessions", type=int, default=200)
    ap.add_argument("--distortion", default="none", help="ml's distortion model")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    noise = Noise()
    opts = sim_noise_options(noise.fiducial_sigma_mm, noise.robot_rot_sigma_deg,
                             noise.robot_trans_sigma_mm, TOOL_8700340_MM)
    rng = np.random.default_rng([a.seed, a.n])
    truth = Truth.random(rng)
    T = {"X": truth.X, "Y": truth.Y, "Z": truth.Z}
    sq = {"ml": [], "qr36": []}
    place = {"ml": [], "qr36 raw": [], "qr36 orthonormal": []}
    bound, covered, times = [], [], []
    for _ in range(a.sessions):
        _, d = simulate(a.n + 200, rng, plan="eq14", noise=noise, truth=truth)
        A, B, C = d["A"][: a.n], d["marker"][: a.n], d["probe"][: a.n]
        targets = d["probe"][a.n:]
        t0 = time.perf_counter()
        ml = solve(A, B, C, method="ml", distortion=a.distortion, **opts)
        times.append(time.perf_counter() - t0)
        qr = solve(A, B, C, method="qr36")
        sq["ml"].append(np.sum((ml.Y[:3, 3] - truth.Y[:3, 3]) ** 2))
        sq["qr36"].append(np.sum((qr.Y[:3, 3] - truth.Y[:3, 3]) ** 2))
        for name, cal, raw in (("ml", ml, True), ("qr36 raw", qr, True),
                               ("qr36 orthonormal", qr, False)):
            Y, Z = (cal.used()["Y"], cal.used()["Z"]) if raw else (cal.Y, cal.Z)
            place[name].append(coil_placement_errors(targets, Y, Z, truth.Y, truth.Z).mean())
        bound.append(translation_rms_bound(crb(A, B, C, T, opts)) ** 2)
        u = ml.uncertainty
        err = coil_placement_errors(u["target"][None], ml.Y, ml.Z, truth.Y, truth.Z)[0]
        covered.append(err <= u["coil_centre_mm"]["p95"])
    b = float(np.sqrt(np.mean(bound)))
    print(f"n = {a.n}, {a.sessions} sessions, ml distortion {a.distortion!r}")
    print(f"  Cramér–Rao bound, RMS error of Y's translation: {b:.4f} mm")
    pre = "" if a.distortion == "none" else f"{a.distortion}_"
    fig: dict[str, float] = {f"{pre}sessions_n{a.n}": a.sessions,
                             f"{pre}bound_mm_n{a.n}": round(b, 4)}
    for k, v in sq.items():
        rms = float(np.sqrt(np.mean(v)))
        print(f"  {k:<5} RMS error of Y's translation {rms:.4f} mm = {rms / b:.3f} × the bound")
        fig[f"{pre}{k}_y_rms_mm_n{a.n}"] = round(rms, 4)
        fig[f"{pre}{k}_over_bound_n{a.n}"] = round(rms / b, 3)
    print("  mean coil placement error: " + ", ".join(f"{k} {np.mean(v):.4f} mm"
                                                     for k, v in place.items()))
    print(f"  ml's 95 % coil-centre interval covers {np.mean(covered):.1%} of the sessions; "
          f"median ml solve {1e3 * np.median(times):.0f} ms")
    for k, v in place.items():
        fig[f"{pre}{k.replace(' ', '_')}_coil_mm_n{a.n}"] = round(float(np.mean(v)), 4)
    fig[f"{pre}covered_pct_n{a.n}"] = round(100 * float(np.mean(covered)), 1)
    fig[f"{pre}ml_ms_n{a.n}"] = round(1e3 * float(np.median(times)))
    record("ml_bound", fig)


if __name__ == "__main__":
    main()
