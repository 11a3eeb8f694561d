"""Adaptive acquisition on the simulated rig: is its predicted coil-placement error honest, and
what do chosen poses buy over random ones (docs/methods.md, "Adaptive acquisition").

    .venv/bin/python benchmarks/adaptive_coverage.py [--runs 40] [--conditions all]
        [--table-rigs 5] [--config configs/mock-ur-polaris.yaml] [--settle-s 0.5]
        [--table-samples 20]

The rig is the config's mock rig (truth, noise, P0), driven directly (tmscal.sim.SimRig:
move_flange, then ``observe(body, n)`` averaged), on the fast clock. Each of ``--runs`` adaptive
runs has its own rig seed and averages 20, 40, 60, 80 or 100 frames per pose (in turn). The
decisions are tmscal.calib.prediction's, in the order tmscal.acquisition.adaptive_run takes them:
the bootstrap, then predict → stop_reason → choose_next (the L-optimal pose per second of
robot time) until it stops. The candidates are the config's plan with ``adaptive.pool``
poses; robot time is the move by tmscal.motion at the config's speed and acceleration caps +
``--settle-s`` + frames / frame rate. Printed per run: poses used, the stopping reason, the
predicted error (mean over the region at the confidence), the true error against the rig's
truth (``true_coil_error``), whether it is covered, and the simulated robot time; then the
share of runs with true ≤ predicted beside the confidence (with its 95 % binomial interval).

Each of ``--conditions`` (``CONDITIONS``; issue 21) runs ``--runs`` such runs: the config's
noise ("default"); the robot's translation or rotation σ 3× or ⅓× (ml starts from its
defaults and must find the noise in the residuals); a +0.1 % tracker scale (the prediction
fits an isotropic scale: docs/methods.md, "Adaptive acquisition"); a UR5e under the rig with
realistic kinematic errors (``make_arm("ur5e", "realistic", seed)``): the robot moves in
joint space, the true error is
where the true arm takes the flange for each command, and the prediction counts the arm's
error as model error, as it does for a session whose joints follow its arm. A summary of the
coverage per condition with its 95 % Wilson interval ends the output (goal: ≥ 90 %). What it
prints is recorded in benchmarks/out/adaptive_coverage.json (``benchmarks/figures.py``).

Then the table of the issue on the same rig, ``--table-rigs`` rig seeds: the mean true
coil-placement error over the region for k = 6, 10, 14, 20 poses, random pool poses solved
by QR36 (and by ml), against the adaptive selection (no stop) solved by ml, choosing per second
of robot time (as a run does) and per pose (every candidate costing the same), each with the
simulated robot time to the k-th pose.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np
from figures import record

from tmscal.acquisition.sample import spread_of
from tmscal.calib import prediction as ad
from tmscal.calib import solve
from tmscal.config import load_config
from tmscal.geometry import pose_mean
from tmscal.motion import move_duration
from tmscal.poses import make_plan
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, make_arm, tms_rig_truth

KS = (6, 10, 14, 20)


class Run:
    """One simulated acquisition: the rig, the poses measured and their spreads."""

    def __init__(self, rig: SimRig, samples: int) -> None:
        self.rig, self.samples = rig, samples
        self.A: list[np.ndarray] = []
        self.bodies: dict[str, list[np.ndarray]] = {"marker": [], "probe": []}
        self.spreads: list[dict] = []
        self.moving_s = 0.0

    def measure(self, P: np.ndarray, speed: float, accel: float) -> None:
        self.moving_s += move_duration(self.rig.commanded, P, speed, accel)
        self.rig.move_flange(P)
        self.A.append(self.rig.reported_flange())
        rec: dict = {"spread": {}, "samples": {}}
        for body, key in (("marker", "B"), ("probe", "C")):
            obs = self.rig.observe(body, self.samples)
            m = pose_mean(obs)
            self.bodies[body].append(m)
            rec["spread"][body] = spread_of(obs, m)
            rec["samples"][key] = self.samples
        self.spreads.append(rec)

    def arrays(self) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        if not self.A:
            return None, None, None
        return (np.array(self.A), np.array(self.bodies["marker"]),
                np.array(self.bodies["probe"]))


def adaptive_run(rig: SimRig, pool: np.ndarray, settings: ad.AdaptiveSettings, samples: int,
                 caps: tuple[float, float], per_pose_s: float, record: tuple[int, ...] = (),
                 per_second: bool = True, model_error: bool = False
                 ) -> tuple[str, ad.Prediction, Run, dict[int, tuple[ad.Prediction, float]]]:
    """The bootstrap, then predict → stop_reason → choose_next until it stops; (the stopping
    reason, the last prediction, the run, {k: (prediction, robot s)} at the ``record`` pose
    counts). ``per_second`` False: every candidate costs the same (the design per pose)."""
    run = Run(rig, samples)
    used = ad.bootstrap_indices(pool, settings.bootstrap_poses(2), TMS_RIG_P0)
    for i in used:
        run.measure(pool[i], *caps)
    seen: dict[int, tuple[ad.Prediction, float]] = {}
    while True:
        A, B, C = run.arrays()
        pred = ad.predict(A, B, C, pool[:settings.region], settings, model_error=model_error,
                          spreads=run.spreads)
        if len(used) in record:
            seen[len(used)] = (pred, run.moving_s + per_pose_s * len(used))
        why = ad.stop_reason(pred, len(used), settings)
        if why is not None:
            return why, pred, run, seen
        avail = np.ones(len(pool), dtype=bool)
        avail[used] = False
        cost = ad.candidate_cost_s(rig.commanded, pool, *caps, per_pose_s) if per_second \
            else np.ones(len(pool))
        i, _ = ad.choose_next(pred, pool, avail, cost)
        used.append(i)
        run.measure(pool[i], *caps)


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson interval of a binomial share k/n."""
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return c - h, c + h


#: the coverage conditions: name → (changes to the config's mock noise, arm errors)
CONDITIONS = {
    "default": ({}, None),
    "robot translation 3x": ({"robot_trans_sigma_mm": 3.0}, None),
    "robot translation 1/3x": ({"robot_trans_sigma_mm": 1 / 3}, None),
    "robot rotation 3x": ({"robot_rot_sigma_deg": 3.0}, None),
    "robot rotation 1/3x": ({"robot_rot_sigma_deg": 1 / 3}, None),
    "tracker scale +0.1 %": ({"tracker_scale": 1.001}, None),
    "realistic arm errors": ({}, "ur5e"),
}


def condition_rig(name: str, base: Noise, seed: int) -> tuple[SimRig, bool]:
    """The rig of one coverage condition (CONDITIONS: the config's noise with the robot's
    translation or rotation σ multiplied, a tracker scale, or a UR5e with realistic arm
    errors drawn from ``seed``) and whether the arm's error counts as model error."""
    from dataclasses import replace

    change, arm = CONDITIONS[name]
    kw = {k: (getattr(base, k) * v if k.startswith("robot") else v) for k, v in change.items()}
    noise = replace(base, **kw)
    pair = None if arm is None else make_arm(arm, "realistic", seed)
    return SimRig(tms_rig_truth(), noise, np.random.default_rng(seed), start=TMS_RIG_P0,
                  arm=pair), arm is not None


def reached_by(rig: SimRig):
    """Where the flange really goes for commanded poses (n, 4, 4) mm: the rig's true arm at
    the joints its controller solves for (no per-move noise); None without an arm."""
    if rig.arm is None:
        return None
    pair = rig.arm

    def reached(A_cmd: np.ndarray) -> np.ndarray:
        q0 = rig.joints()
        return np.stack([pair.actual(pair.solve(T, q0)) for T in A_cmd])
    return reached


def coverage(a: argparse.Namespace, cfg, pool: np.ndarray, settings: ad.AdaptiveSettings,
             noise: Noise, name: str) -> tuple[int, int]:
    """One condition's adaptive runs; prints a line per run and the share covered."""
    truth = tms_rig_truth()
    region = pool[:settings.region]
    caps = (cfg.robot.speed_mm_s, cfg.robot.accel_mm_s2)
    rate = cfg.tracker.frame_rate_hz
    print(f"\n== {name}")
    print(f"{'seed':>5} {'frames':>6} {'poses':>5} {'stop':>9} {'predicted':>9} {'true':>7} "
          f"{'covered':>7} {'robot s':>7} {'robot σ mm':>10} {'σ deg':>7}")
    covered, rows = 0, []
    for r in range(a.runs):
        seed = a.seed + r
        samples = (20, 40, 60, 80, 100)[r % 5]
        rig, model_error = condition_rig(name, noise, seed)
        per_pose = a.settle_s + samples / rate
        why, p, run, _ = adaptive_run(rig, pool, settings, samples, caps, per_pose,
                                      model_error=model_error)
        true = ad.true_coil_error(p.calibration, truth.Y, truth.Z, region, reached_by(rig),
                                  rig.noise.tracker_distortion if rig.noise.distorted else None)
        ok = true <= p.coil_mm
        covered += ok
        robot_s = run.moving_s + per_pose * len(run.A)
        rows.append((len(run.A), p.coil_mm, true, robot_s))
        print(f"{seed:>5} {samples:>6} {len(run.A):>5} {why:>9} {p.coil_mm:>9.4f} "
              f"{true:>7.4f} {'yes' if ok else 'NO':>7} {robot_s:>7.1f} "
              f"{p.noise[0]:>10.4f} {np.degrees(p.noise[1]) * np.sqrt(3):>7.4f}", flush=True)
    lo, hi = wilson(covered, a.runs)
    m = np.mean(rows, axis=0)
    print(f"{name}: covered (true ≤ predicted) {covered}/{a.runs} = {covered / a.runs:.1%} "
          f"(95 % interval {lo:.1%}–{hi:.1%}) at confidence {settings.confidence:.0%}; "
          f"mean {m[0]:.1f} poses, predicted {m[1]:.4f} mm, true {m[2]:.4f} mm, "
          f"robot time {m[3]:.1f} s")
    key = slug(name)
    record("adaptive_coverage", {
        f"covered_{key}": covered, f"runs_{key}": a.runs,
        f"covered_pct_{key}": round(100 * covered / a.runs, 1),
        f"interval_lo_pct_{key}": round(100 * lo, 1), f"interval_hi_pct_{key}": round(100 * hi, 1),
        f"mean_poses_{key}": round(float(m[0]), 1), f"predicted_mm_{key}": round(float(m[1]), 4),
        f"true_mm_{key}": round(float(m[2]), 4), f"robot_s_{key}": round(float(m[3]), 1)})
    return covered, a.runs


def slug(name: str) -> str:
    """A condition's name as a figure name: "robot translation 1/3x" → robot_translation_1_3x."""
    return "_".join("".join(c if c.isalnum() else " " for c in name).split())


TABLE = (("qr36", "random pool poses, QR36"), ("ml", "random pool poses, ml"),
         ("per_s", "adaptive per second, ml"), ("per_pose", "adaptive per pose, ml"))


def table(a: argparse.Namespace, cfg, pool: np.ndarray, noise: Noise) -> None:
    """The issue's table: mean true error at k poses, random against adaptive, and the
    simulated robot time to the k-th pose."""
    truth = tms_rig_truth()
    settings = ad.AdaptiveSettings(target_mm=1e-9, max_poses=max(KS), pool=len(pool),
                                   region=a.region)
    region = pool[:settings.region]
    caps = (cfg.robot.speed_mm_s, cfg.robot.accel_mm_s2)
    per_pose = a.settle_s + a.table_samples / cfg.tracker.frame_rate_hz
    err: dict[str, dict[int, list[float]]] = {m: {k: [] for k in KS} for m, _ in TABLE}
    secs: dict[str, dict[int, list[float]]] = {m: {k: [] for k in KS} for m, _ in TABLE}
    for r in range(a.table_rigs):
        seed = 10_000 + a.seed + r
        for m, per_s in (("per_s", True), ("per_pose", False)):
            rig = SimRig(truth, noise, np.random.default_rng(seed), start=TMS_RIG_P0)
            seen = adaptive_run(rig, pool, settings, a.table_samples, caps, per_pose, KS,
                                per_s)[3]
            for k in KS:
                err[m][k].append(ad.true_coil_error(seen[k][0].calibration, truth.Y, truth.Z,
                                                    region))
                secs[m][k].append(seen[k][1])
        rig = SimRig(truth, noise, np.random.default_rng(seed), start=TMS_RIG_P0)
        run = Run(rig, a.table_samples)
        for j, i in enumerate(np.random.default_rng(seed).permutation(len(pool))[:max(KS)]):
            run.measure(pool[i], *caps)
            if j + 1 in KS:
                for m in ("qr36", "ml"):
                    secs[m][j + 1].append(run.moving_s + per_pose * (j + 1))
        A, B, C = run.arrays()
        for k in KS:
            for m in ("qr36", "ml"):
                opts = {"distortion": "none", "spreads": run.spreads[:k]} if m == "ml" else {}
                cal = solve(A[:k], B[:k], C[:k], method=m, **opts)
                err[m][k].append(ad.true_coil_error(cal, truth.Y, truth.Z, region))
    print(f"\nmean true coil-placement error over the region, mm (simulated robot time to the "
          f"k-th pose, s); {a.table_rigs} rig seeds, {a.table_samples} frames per pose")
    print(f"{'k':<28}" + "".join(f"{k:>15}" for k in KS))
    for m, label in TABLE:
        print(f"{label:<28}" + "".join(f"{np.mean(err[m][k]):>8.3f} ({np.mean(secs[m][k]):>4.0f})"
                                       for k in KS))
    record("adaptive_coverage", {f"table_{m}_mm_k{k}": np.mean(err[m][k]) for m, _ in TABLE
                                 for k in KS})
    record("adaptive_coverage", {f"table_{m}_s_k{k}": round(float(np.mean(secs[m][k])))
                                 for m, _ in TABLE for k in KS})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/mock-ur-polaris.yaml",
                    help="rig config: its mock noise, plan, robot caps and frame rate")
    ap.add_argument("--runs", type=int, default=40,
                    help="adaptive runs per coverage condition")
    ap.add_argument("--conditions", default="all",
                    help=f"comma-separated conditions (default all: {', '.join(CONDITIONS)})")
    ap.add_argument("--table-rigs", type=int, default=5, help="rig seeds for the k table")
    ap.add_argument("--table-samples", type=int, default=20, help="frames per pose, table")
    ap.add_argument("--settle-s", type=float, default=0.5,
                    help="settling time per pose in the robot-time cost (s)")
    ap.add_argument("--region", type=int, default=None, help="region poses (default: config)")
    ap.add_argument("--seed", type=int, default=0, help="first rig seed")
    a = ap.parse_args()
    cfg = load_config(a.config, check_files=False)
    ac = cfg.adaptive
    a.region = a.region or ac.region
    settings = ad.AdaptiveSettings(ac.target_mm, ac.confidence, ac.max_poses, ac.bootstrap,
                                   ac.pool, a.region)
    noise = Noise(**cfg.mock.noise)
    pool = make_plan(cfg.plan.kind, TMS_RIG_P0, settings.pool, cfg.plan.seed,
                     cfg.plan.radius_mm, cfg.plan.rotation_deg)
    print("$ " + " ".join(sys.argv))
    print(f"config {a.config}: noise {cfg.mock.noise}; plan {cfg.plan.kind} ±"
          f"{cfg.plan.radius_mm} mm ±{cfg.plan.rotation_deg}° seed {cfg.plan.seed}; robot caps "
          f"{cfg.robot.speed_mm_s} mm/s, {cfg.robot.accel_mm_s2} mm/s²; "
          f"{cfg.tracker.frame_rate_hz} Hz; settle {a.settle_s} s")
    print(f"settings {settings}\n")
    t0 = time.perf_counter()
    names = list(CONDITIONS) if a.conditions == "all" else a.conditions.split(",")
    summary = {c: coverage(a, cfg, pool, settings, noise, c) for c in names}
    print(f"\ncoverage of the {settings.confidence:.0%} prediction (goal ≥ 90 %), "
          f"{a.runs} adaptive runs per condition:")
    for c, (k, n) in summary.items():
        lo, hi = wilson(k, n)
        print(f"  {c:<24} {k:>3}/{n} = {k / n:6.1%}  (95 % interval {lo:.1%}–{hi:.1%})")
    if a.table_rigs:
        table(a, cfg, pool, noise)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
