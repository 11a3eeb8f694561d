"""Adaptive acquisition on the simulated rig: is its predicted coil-placement error honest, and
what do chosen poses buy over random ones (docs/methods.md, "Adaptive acquisition").

    .venv/bin/python benchmarks/adaptive_coverage.py [--runs 50] [--table-rigs 5]
        [--config configs/mock-ur-polaris.yaml] [--settle-s 0.5] [--table-samples 20]

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

from tmscal.acquisition.sample import spread_of
from tmscal.calib import prediction as ad
from tmscal.calib import solve
from tmscal.config import load_config
from tmscal.geometry import pose_mean
from tmscal.motion import move_duration
from tmscal.poses import make_plan
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

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
                 per_second: bool = True
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
        pred = ad.predict(A, B, C, pool[:settings.region], settings, spreads=run.spreads)
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


def coverage(a: argparse.Namespace, cfg, pool: np.ndarray, settings: ad.AdaptiveSettings,
             noise: Noise) -> None:
    truth = tms_rig_truth()
    region = pool[:settings.region]
    caps = (cfg.robot.speed_mm_s, cfg.robot.accel_mm_s2)
    rate = cfg.tracker.frame_rate_hz
    print(f"{'seed':>5} {'frames':>6} {'poses':>5} {'stop':>9} {'predicted':>9} {'true':>7} "
          f"{'covered':>7} {'robot s':>7}")
    covered, rows = 0, []
    for r in range(a.runs):
        seed = a.seed + r
        samples = (20, 40, 60, 80, 100)[r % 5]
        rig = SimRig(truth, noise, np.random.default_rng(seed), start=TMS_RIG_P0)
        per_pose = a.settle_s + samples / rate
        why, p, run, _ = adaptive_run(rig, pool, settings, samples, caps, per_pose)
        true = ad.true_coil_error(p.calibration, truth.Y, truth.Z, region)
        ok = true <= p.coil_mm
        covered += ok
        robot_s = run.moving_s + per_pose * len(run.A)
        rows.append((len(run.A), p.coil_mm, true, robot_s))
        print(f"{seed:>5} {samples:>6} {len(run.A):>5} {why:>9} {p.coil_mm:>9.4f} "
              f"{true:>7.4f} {'yes' if ok else 'NO':>7} {robot_s:>7.1f}", flush=True)
    lo, hi = wilson(covered, a.runs)
    m = np.mean(rows, axis=0)
    print(f"\ncovered (true ≤ predicted): {covered}/{a.runs} = {covered / a.runs:.1%} "
          f"(95 % interval {lo:.1%}–{hi:.1%}) at confidence {settings.confidence:.0%}")
    print(f"mean over runs: {m[0]:.1f} poses, predicted {m[1]:.4f} mm, true {m[2]:.4f} mm, "
          f"simulated robot time {m[3]:.1f} s")


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/mock-ur-polaris.yaml",
                    help="rig config: its mock noise, plan, robot caps and frame rate")
    ap.add_argument("--runs", type=int, default=50, help="adaptive runs for the coverage")
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
    coverage(a, cfg, pool, settings, noise)
    table(a, cfg, pool, noise)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
