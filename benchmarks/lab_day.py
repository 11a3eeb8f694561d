"""Lab-day benchmark: what moved (the daily check's diagnosis) and the re-registration of only
that (``--update``), on simulated sessions (docs/lab-day.md).

1. Diagnosis. For each change type, ``--sims`` simulated days: a calibration (QR36) solved on
   40 poses of a random rig (Wang et al. 2018's simulation, Eq. 14 plan, 10 tracker frames
   averaged per pose), its noise model as ``tmscal solve -o`` stores it, then 10 poses of
   the rig after the change, diagnosed as ``tmscal solve TODAY --calib CAL`` does. Changes
   (random direction): nothing; the tracker moved 1–300 mm and 0.5–30° (log-uniform); the
   coil re-seated, the marker moved on the coil, the coil's centre changed: 0.3–2 mm and
   0.2–2°; an arm joint offset of 0.05–0.3° (a UR5e, the tracker poses with the same noise).
   Prints the share diagnosed correctly and, for "nothing", the share where a change was
   claimed. At the robot noise of the simulation ×1, ×3 and ×⅓ (``--scales``).
2. Re-registration. A tracker moved as above; ``--update z`` from 3, 5 and 10 poses against
   a full QR36 recalibration from the same poses and from 40: the true coil-placement error
   (mm, mean over 50 targets of the plan's region and over the sims).

Usage: ``python benchmarks/lab_day.py [--sims 50] [--scales 1,3,0.333] [--update-sims 30]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from tmscal.calib import diagnose as dg
from tmscal.calib import solve
from tmscal.calib.kinematics.arms import arm_by_name
from tmscal.calib.kinematics.model import base_from_flange
from tmscal.calib.metrics import coil_placement_errors
from tmscal.geometry import invert, make_pose, matrix_from_rotvec
from tmscal.sim.changes import changed
from tmscal.sim.rig import Noise
from tmscal.sim.study import simulate

TYPES = ("none", "tracker", "coil", "marker", "coil_centre", "arm")


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _change(rng: np.random.Generator, kind: str) -> tuple[list[float], list[float]]:
    if kind == "tracker":
        mm, deg = _loguniform(rng, 1, 300), _loguniform(rng, 0.5, 30)
    else:
        mm, deg = _loguniform(rng, 0.3, 2), _loguniform(rng, 0.2, 2)
    return list(mm * _unit(rng)), list(deg * _unit(rng))


def _noise(scale: float) -> Noise:
    return Noise(robot_rot_sigma_deg=0.05 * scale, robot_trans_sigma_mm=0.05 * scale)


def _calibrated(rng: np.random.Generator, noise: Noise):
    truth, d = simulate(40, rng, noise=noise, samples=10)
    cal = solve(d["A"], d["marker"], d["probe"], method="qr36")
    nm = dg.calibration_noise(cal, d["A"], d["marker"], d["probe"])
    return truth, cal, nm


def _rigid_day(rng: np.random.Generator, kind: str, noise: Noise) -> str:
    truth, cal, nm = _calibrated(rng, noise)
    after = truth if kind == "none" else changed(truth, kind, *_change(rng, kind))
    _, e = simulate(10, rng, noise=noise, samples=10, truth=after)
    return dg.diagnose(dg.frames(cal, e["A"], e["marker"], e["probe"]), nm).changed


ARM = arm_by_name("ur5e")
Q0 = np.array([0.0, -1.3, 1.6, -1.9, -1.57, 0.3])


def _arm_day(rng: np.random.Generator, noise: Noise) -> str:
    """A UR5e (nominal kinematics, joints known): calibration on 40 poses, today 10 poses
    after one joint's offset changed; tracker poses with the tracker noise of 10 averaged
    frames and the robot noise of ``noise``, as tracker-frame perturbations."""
    truth = simulate(1, rng)[0]
    sig_t = np.hypot(0.05 / np.sqrt(10), noise.robot_trans_sigma_mm)
    sig_r = np.hypot(0.02 / np.sqrt(10), noise.robot_rot_sigma_deg)

    def poses(n: int, delta: np.ndarray):
        q = Q0 + rng.uniform(-0.35, 0.35, (n, 6))
        A = base_from_flange(ARM, q)
        At = base_from_flange(ARM, q + delta)
        out = []
        for Yb in (truth.X, truth.Y):
            N = invert(truth.Z) @ At @ Yb
            for i in range(n):
                N[i] = N[i] @ make_pose(matrix_from_rotvec(np.radians(
                    rng.normal(0, sig_r, 3))), rng.normal(0, sig_t, 3))
            out.append(N)
        return q, A, out[0], out[1]

    q, A, B, C = poses(40, np.zeros(6))
    cal = solve(A, B, C, method="qr36")
    nm = dg.calibration_noise(cal, A, B, C)
    delta = np.zeros(6)
    delta[rng.integers(0, 6)] = np.radians(_loguniform(rng, 0.05, 0.3)) * rng.choice([-1, 1])
    q, A, B, C = poses(10, delta)
    fr = dg.frames(cal, A, B, C, q, lambda qq: base_from_flange(ARM, qq))
    return dg.diagnose(fr, nm).changed


def diagnosis_table(sims: int, scales: list[float], seed: int) -> None:
    print(f"1. diagnosis: {sims} simulated days per change, 10 poses each "
          "(share diagnosed correctly; for 'none': share where a change was claimed)")
    print(f"  {'robot noise':<12}" + "".join(f"{t:>13}" for t in TYPES) + f"{'s/day':>8}")
    for scale in scales:
        rng = np.random.default_rng(seed)
        noise = _noise(scale)
        row = []
        t0 = time.perf_counter()
        for kind in TYPES:
            got = [_arm_day(rng, noise) if kind == "arm" else _rigid_day(rng, kind, noise)
                   for _ in range(sims)]
            if kind == "none":
                row.append(f"{100 * np.mean([g != 'none' for g in got]):.0f} % claimed")
            else:
                row.append(f"{100 * np.mean([g == kind for g in got]):.0f} %")
        dt = (time.perf_counter() - t0) / (sims * len(TYPES))
        print(f"  ×{scale:<11.3g}" + "".join(f"{c:>13}" for c in row) + f"{dt:>8.2f}")


def update_table(sims: int, seed: int) -> None:
    print(f"\n2. re-registration after a tracker move (1–300 mm, 0.5–30°), {sims} sims: true "
          "coil-placement error, mm (mean over 50 targets and the sims)")
    rng = np.random.default_rng(seed + 1)
    res: dict[str, list[float]] = {}
    refused = 0
    why: list[str] = []
    for _ in range(sims):
        truth, cal, nm = _calibrated(rng, _noise(1.0))
        after = changed(truth, "tracker", *_change(rng, "tracker"))
        _, e = simulate(50, rng, noise=_noise(1.0), samples=10, truth=after)
        targets = invert(after.Z) @ e["A"] @ after.Y   # where the coil should go
        for n in (3, 5, 10):
            sl = slice(0, n)
            fr = dg.frames(cal, e["A"][sl], e["marker"][sl], e["probe"][sl])
            try:
                new = dg.updated(cal, dg.update(fr, nm, ["z"]))
                err = coil_placement_errors(targets, new.Y_raw, new.Z_raw, after.Y, after.Z)
                res.setdefault(f"--update z, {n} poses", []).append(float(err.mean()))
            except dg.UpdateRefused as ex:
                refused += 1
                why.append(f"{n} poses: {ex}")
            full = solve(e["A"][sl], e["marker"][sl], e["probe"][sl], method="qr36")
            err = coil_placement_errors(targets, full.Y_raw, full.Z_raw, after.Y, after.Z)
            res.setdefault(f"full QR36, {n} poses", []).append(float(err.mean()))
        _, f = simulate(40, rng, noise=_noise(1.0), samples=10, truth=after)
        full = solve(f["A"], f["marker"], f["probe"], method="qr36")
        err = coil_placement_errors(targets, full.Y_raw, full.Z_raw, after.Y, after.Z)
        res.setdefault("full QR36, 40 poses", []).append(float(err.mean()))
    for k, v in res.items():
        print(f"  {k:<26} mean {np.mean(v):.4f}  max {np.max(v):.4f}  (n = {len(v)})")
    print(f"  updates refused (no second change was made): {refused} of {3 * sims}")
    for w in why:
        print(f"    {w}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sims", type=int, default=50)
    ap.add_argument("--scales", default="1,3,0.333")
    ap.add_argument("--update-sims", type=int, default=30)
    ap.add_argument("--seed", type=int, default=2026)
    a = ap.parse_args()
    if a.sims:
        diagnosis_table(a.sims, [float(s) for s in a.scales.split(",")], a.seed)
    update_table(a.update_sims, a.seed)


if __name__ == "__main__":
    main()
