"""The arm's kinematics estimated from the tracker (docs/kinematics.md, issue 20): what it buys
on the mock rigs with realistic arm errors, on simulated sessions, and how many poses (and how
much robot time) it needs with the default plan and with the joints plan.

    .venv/bin/python benchmarks/kinematics.py [--seeds 3] [--first-seed 1] [--poses 40]
                                              [--ladder 10,15,20,30,40] [--samples 100]
                                              [--noise-scale 1] [--wrench-poses 30]
                                              [--ft-samples 50] [--skip-sim] [--skip-rig]
                                              [--skip-wrench]

1. **Mock rig** (``configs/mock-ur-polaris-kin.yaml``, a UR5e, and
   ``configs/mock-denso-polaris-kin.yaml``, a VS-060; realistic arm errors drawn from the mock seed
   1…seeds; a temporary copy on a loopback address of its own, the tracker on a pty): the mocks in
   a child process and the acquisition through the real drivers and wire protocols, as ``tmscal
   demo --kinematics estimate`` runs them (``spawn_mock_rig``, ``acquire``; ``--first-seed`` shifts
   the seeds, ``--noise-scale`` multiplies the mock's fiducial and robot noise). On each session,
   the first ``--poses`` poses of its Eq. 14 plan: QR36 and ml solved with the controller's NOMINAL
   arm (A as reported), with the ESTIMATED arm (ml: ``solve --kinematics estimate``; QR36: A
   recomputed from the joints with the arm ml estimated) and with the TRUE arm (A recomputed with
   the mock's true arm: the ceiling); the same on the first ``--poses`` poses of a joints plan
   (part 2) on the same rig.
   Coil placement (mm, mean) against the mock rig's truth through each calibration's flange
   commands (``solving.kinematics.coil_placement``: the truth's controller solves its
   nominal kinematics for the command and the true arm goes there), over 100 targets: the
   coil poses the true rig produces from an Eq. 14 plan (seed 99, ±100 mm, ±10°) around the
   session's P0, the workspace a TMS session uses. Goal: estimated ≤ 1.5 × true.
2. **Poses needed** on the same rigs and seeds: sessions of the default Eq. 14 plan (±100 mm,
   ±10°) and of the joints plan (``plan: {kind: joints, radius_mm: 200, rotation_deg: 20}``,
   the configs' safety limits), the estimated arm's (ml) placement over the same targets
   after the first n poses (any prefix of a plan is the shorter plan) for n in ``--ladder``;
   the fewest poses whose placement is ≤ 0.05 mm (mean over the seeds, and on every seed),
   and the robot time they take.
4. **Wrench rows** (``configs/mock-ur-polaris-kin-ft.yaml``: the UR5e rig with its built-in
   wrist sensor, whose mock reads the TRUE arm's gravity wrench plus noise; seeds 1…seeds):
   sessions of ``--wrench-poses`` joints-plan poses with ``--ft-samples`` readings averaged
   per pose; ``solve --kinematics estimate`` with the wrench rows (every pose has a wrench)
   and on the same session with the wrenches removed: the coil placement (mm, the same
   targets) both ways, and the tool's mass (kg), centre of gravity (mm) and the base tilt
   (deg) the wrench rows find against the true arm's.
3. **Simulated sessions** (``tmscal simulate --arm ur5e``, realistic errors, 40 Eq. 14 poses
   of 10 samples, seeds 1…seeds) at two noise levels (tracker fiducial σ and robot σ 0.05 mm
   / 0.05°, and 0.1 / 0.1°): 5-fold cross-validated e_t (mm) of the estimated model against
   raw QR24 (Wang et al.'s non-orthonormal matrices) and rigid (orthonormalised) QR36.

Robot time (s) is the motion model, not the fast mock's clock: straight Cartesian moves from
P0 through every commanded pose at the config's speed and acceleration caps
(``tmscal.motion.move_duration``; a move the safety layer splits through P0 takes longer)
+ a 1 s settle + ``--samples`` / frame rate per pose. Takes about 4 minutes of CPU with the
defaults (12 min of wall time on a shared, busy 2-core machine; ``--skip-sim``,
``--skip-rig`` and ``--skip-wrench`` for parts, ``--seeds`` for fewer).
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from figures import record

from tmscal.acquisition.run import acquire
from tmscal.calib.kinematics import ARMS, forward
from tmscal.calib.kinematics.ik import inverse
from tmscal.config import load_config
from tmscal.mocks.launch import build_sim_rig, spawn_mock_rig
from tmscal.motion import move_duration
from tmscal.net import split_endpoint
from tmscal.poses import make_plan
from tmscal.session import read_session, write_session
from tmscal.solving.kinematics import coil_placement
from tmscal.solving.solve import solve

CONFIGS = Path(__file__).resolve().parents[1] / "tmscal" / "data" / "configs"
RIGS = {"ur5e": ("mock-ur-polaris-kin.yaml", "127.0.0.187"),   # ur_rtde's ports are fixed
        "vs060": ("mock-denso-polaris-kin.yaml", "127.0.0.188"),
        "ur5e-ft": ("mock-ur-polaris-kin-ft.yaml", "127.0.0.189")}
JOINTS_PLAN = {"kind": "joints", "radius_mm": 200, "rotation_deg": 20}
GOAL_MM = 0.05
SETTLE_S = 1.0


def _config(tmp: Path, arm: str, seed: int, plan: dict[str, Any], poses: int,
            samples: int, noise_scale: float = 1.0) -> Path:
    base, host = RIGS[arm]
    data = yaml.safe_load((CONFIGS / base).read_text())
    data["tracker"]["tools"] = {k: str(CONFIGS / v) for k, v in data["tracker"]["tools"].items()}
    data["robot"]["host"] = host
    if data["robot"]["driver"] == "denso":
        data["robot"]["port"] = 0
    data["plan"] = {**data["plan"], **plan, "poses": poses}
    data["sampling"]["samples"] = samples
    data["mock"]["seed"] = seed
    data["mock"]["noise"] = {k: v * noise_scale for k, v in data["mock"]["noise"].items()}
    p = tmp / f"{arm}-{seed}-{plan.get('kind', 'eq14')}.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _acquire(cfg_path: Path, out: Path) -> Any:
    """A session on the mock rig through the real drivers (the mocks in a child process), its
    header carrying the rig's truth as the demo puts it; read back."""
    cfg = load_config(cfg_path)
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        host, port = split_endpoint(mp.endpoints["robot"])
        acquire(cfg, out, tracker_port=mp.endpoints["tracker"], robot_host=host,
                robot_port=port)
    s = read_session(out)
    full = out.with_suffix(".truth.jsonl")
    write_session(full, {**s.header, "truth": build_sim_rig(cfg).truth.as_dict()}, s.poses)
    return read_session(full)


def _targets(session: Any, n: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """(C (n, 4, 4) tracker ← probe mm, q (n, dof) rad): the coil poses the true rig produces
    from an Eq. 14 plan (seed 99) around the session's P0, and the joints its controller
    reaches them with."""
    ta, t = session.truth_arm, session.truth
    nominal, true, mount = ta["nominal"], ta["true"], np.asarray(ta["mount"])
    P = make_plan("eq14", np.array(session.header["plan"]["p0"]), n, 99, 100.0, 10.0)
    to_base = np.linalg.inv(mount @ nominal.base)
    q, here = [], np.array(ARMS[ta["name"]].home_q)
    for Pi in P:
        qi = inverse(nominal, to_base @ Pi, [here])
        assert qi is not None, "a target out of reach"
        q.append(qi)
        here = qi
    q = np.array(q)
    C = np.linalg.inv(t["Z"]) @ mount @ forward(true, q) @ t["Y"]
    return C, q


def _placement(cal: Any, session: Any, targets: tuple[np.ndarray, np.ndarray]) -> float:
    C, q = targets
    return float(coil_placement(cal, C, session.truth, session.truth_arm, q).mean())


def _prefix(session: Any, n: int) -> Any:
    return replace(session, poses=session.poses[:n])


def _robot_time(session: Any, cfg_path: Path, samples: int) -> np.ndarray:
    """Cumulative robot time (s) after each pose (module docstring)."""
    cfg = load_config(cfg_path)
    path = [np.array(session.header["plan"]["p0"])] + [p.commanded for p in session.poses]
    per = SETTLE_S + samples / cfg.tracker.frame_rate_hz
    moves = [move_duration(a, b, cfg.robot.speed_mm_s, cfg.robot.accel_mm_s2)
             for a, b in zip(path[:-1], path[1:], strict=True)]
    return np.cumsum(np.array(moves) + per)


def _three_arms(session: Any, targets: Any) -> dict[str, float]:
    """Placement of QR36 and ml with the nominal, estimated and true arm."""
    out = {}
    est = solve(session, method="ml", kinematics="estimate", in_sample=True).calibration
    arms = {"estimated": est.arm.arm, "true": session.truth_arm["true"]}
    for m in ("qr36", "ml"):
        cal = solve(session, method=m, in_sample=True).calibration
        out[f"{m} nominal"] = _placement(cal, session, targets)
        for what, arm in arms.items():
            if m == "ml" and what == "estimated":
                cal = est
            else:
                cal = solve(session, method=m, kinematics=arm, in_sample=True,
                                       kinematics_source=what).calibration
            out[f"{m} {what}"] = _placement(cal, session, targets)
    return out


def _tag(args: argparse.Namespace) -> str:
    """The figures' name suffix of a run with other seeds or noise ("" for the defaults):
    ``_seeds4`` for --first-seed 4, ``_noise2`` for --noise-scale 2."""
    return ("" if args.first_seed == 1 else f"_seeds{args.first_seed}") + \
        ("" if args.noise_scale == 1 else f"_noise{args.noise_scale:g}".replace(".", "_"))


def rig(args: argparse.Namespace, tmp: Path) -> None:
    n_max = max([args.poses, *args.ladder])
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"## Mock rigs with realistic arm errors (seeds {seeds[0]}..{seeds[-1]}, "
          f"{args.samples} samples per pose, mock noise × {args.noise_scale:g}; coil placement "
          "mm, mean over 100 Eq. 14 targets)\n")
    ladder: dict[tuple[str, str], list[tuple[np.ndarray, np.ndarray]]] = {}
    for arm in RIGS:
        rows: dict[str, list[dict[str, float]]] = {"eq14": [], "joints": []}
        times: dict[str, list[float]] = {"eq14": [], "joints": []}
        for seed in seeds:
            sessions = {}
            for kind, plan in (("eq14", {}), ("joints", JOINTS_PLAN)):
                cfg_path = _config(tmp, arm, seed, plan, n_max, args.samples,
                                   args.noise_scale)
                s = _acquire(cfg_path, tmp / f"{arm}-{seed}-{kind}.jsonl")
                sessions[kind] = (s, _robot_time(s, cfg_path, args.samples))
            targets = _targets(sessions["eq14"][0])
            for kind, (sk, tk) in sessions.items():
                r = _three_arms(_prefix(sk, args.poses), targets)
                rows[kind].append(r)
                times[kind].append(float(tk[args.poses - 1]))
                print(f"{arm} seed {seed}, {args.poses} poses of the {kind} plan, robot time "
                      f"{tk[args.poses - 1]:.0f} s: "
                      + ", ".join(f"{k} {v:.3f}" for k, v in r.items()))
                pl = [_placement(solve(_prefix(sk, n), method="ml", kinematics="estimate",
                                               in_sample=True).calibration, sk, targets)
                      for n in args.ladder]
                ladder.setdefault((arm, kind), []).append(
                    (np.array(pl), tk[np.array(args.ladder) - 1]))
        for kind, rk in rows.items():
            mean = {k: float(np.mean([r[k] for r in rk])) for k in rk[0]}
            print(f"\n{arm}, {args.poses} poses of the {kind} plan (robot time "
                  f"{np.mean(times[kind]):.0f} s), mean over {args.seeds} seeds:")
            print(f"  {'':6}{'nominal arm':>14}{'estimated arm':>16}{'true arm':>12}"
                  f"{'estimated / true':>19}")
            for m in ("qr36", "ml"):
                e, tr = mean[f"{m} estimated"], mean[f"{m} true"]
                print(f"  {m:6}{mean[f'{m} nominal']:>14.4f}{e:>16.4f}{tr:>12.4f}"
                      f"{e / tr:>19.2f}")
                record("kinematics", {f"{arm}_{kind}_{m}_{k}_mm{_tag(args)}": mean[f"{m} {k}"]
                                      for k in ("nominal", "estimated", "true")}
                       | {f"{arm}_{kind}_{m}_ratio{_tag(args)}": e / tr})
        print()
    print(f"## Poses needed: the estimated arm's (ml) coil placement after the first n poses "
          f"(mm, mean over {args.seeds} seeds), robot time (s)\n")
    print(f"  {'arm':6}{'plan':8}" + "".join(f"{n:>9}" for n in args.ladder)
          + f"   ≤ {GOAL_MM} mm: poses (robot s), every seed: poses")
    for (arm, kind), runs in ladder.items():
        pl = np.array([r[0] for r in runs])
        tm = np.array([r[1] for r in runs]).mean(axis=0)
        m = pl.mean(axis=0)
        ok = [i for i in range(len(args.ladder)) if m[i] <= GOAL_MM]
        every = [i for i in range(len(args.ladder)) if (pl[:, i] <= GOAL_MM).all()]
        first = f"{args.ladder[ok[0]]} ({tm[ok[0]]:.0f} s)" if ok else "not reached"
        all_ = f"{args.ladder[every[0]]}" if every else "not reached"
        print(f"  {arm:6}{kind:8}" + "".join(f"{x:>9.4f}" for x in m) + f"   {first}, {all_}")
        print(f"  {'':6}{'time s':8}" + "".join(f"{x:>9.0f}" for x in tm))
        record("kinematics", {f"{arm}_{kind}_{n}_poses_mm{_tag(args)}": x
                              for n, x in zip(args.ladder, m, strict=True)})
        if ok:
            record("kinematics", {f"{arm}_{kind}_goal_poses{_tag(args)}": args.ladder[ok[0]],
                                  f"{arm}_{kind}_goal_s{_tag(args)}": tm[ok[0]]})
    print()


def wrench(args: argparse.Namespace, tmp: Path) -> None:
    """Part 4 (module docstring)."""
    from tmscal.calib.kinematics import rpy_from_matrix

    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        cfg_path = _config(tmp, "ur5e-ft", seed, JOINTS_PLAN, args.wrench_poses, args.samples,
                           args.noise_scale)
        data = yaml.safe_load(cfg_path.read_text())
        data["ft"]["samples"] = args.ft_samples
        cfg_path.write_text(yaml.safe_dump(data))
        s = _acquire(cfg_path, tmp / f"ur5e-ft-{seed}.jsonl")
        assert all(p.wrench is not None for p in s.poses), "a pose without a wrench"
        targets = _targets(s)
        cal_w = solve(s, method="ml", kinematics="estimate", in_sample=True).calibration
        bare = replace(s, poses=[replace(p, wrench=None, wrench_spread=None) for p in s.poses])
        cal_0 = solve(bare, method="ml", kinematics="estimate", in_sample=True).calibration
        w = cal_w.arm.report["wrench"]
        true = build_sim_rig(load_config(cfg_path)).arm_true
        roll, pitch, _ = rpy_from_matrix(true.base)
        e = w["estimate"]
        row = {"with_mm": _placement(cal_w, s, targets),
               "without_mm": _placement(cal_0, s, targets),
               "mass_err_kg": abs(w["tool_mass_kg"] - true.tool_mass_kg),
               "cog_err_mm": float(np.linalg.norm([e[f"cog_{k}"] for k in "xyz"]
                                                  - np.asarray(true.tool_cog_mm))),
               "tilt_err_deg": float(np.degrees(np.hypot(e["base_roll"] - roll,
                                                         e["base_pitch"] - pitch)))}
        rows.append(row)
        print(f"ur5e seed {seed}, {args.wrench_poses} joints-plan poses, {args.ft_samples} "
              f"wrench readings per pose: coil placement with the wrench rows "
              f"{row['with_mm']:.4f} mm, without {row['without_mm']:.4f} mm; tool mass error "
              f"{row['mass_err_kg']:.4f} kg, centre of gravity error {row['cog_err_mm']:.3f} mm, "
              f"base tilt error {row['tilt_err_deg']:.3f} deg", flush=True)
    mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
    print(f"\n## Wrench rows (mean of {len(rows)} seeds): coil placement with "
          f"{mean['with_mm']:.4f} mm / without {mean['without_mm']:.4f} mm "
          f"(ratio {mean['with_mm'] / mean['without_mm']:.2f}); tool mass error "
          f"{mean['mass_err_kg']:.4f} kg, centre of gravity {mean['cog_err_mm']:.3f} mm, "
          f"base tilt {mean['tilt_err_deg']:.3f} deg")
    t = _tag(args)
    record("kinematics", {f"wrench_with_mm{t}": round(mean["with_mm"], 4),
                          f"wrench_without_mm{t}": round(mean["without_mm"], 4),
                          f"wrench_ratio{t}": round(mean["with_mm"] / mean["without_mm"], 2),
                          f"wrench_mass_err_kg{t}": round(mean["mass_err_kg"], 4),
                          f"wrench_cog_err_mm{t}": round(mean["cog_err_mm"], 3),
                          f"wrench_tilt_err_deg{t}": round(mean["tilt_err_deg"], 3)})


def _tmscal(*args: object) -> None:
    r = subprocess.run([sys.executable, "-m", "tmscal.cli", *map(str, args)],
                       capture_output=True, text=True, timeout=600)
    if r.returncode != 0:
        raise SystemExit(f"tmscal {' '.join(map(str, args))} failed:\n{r.stderr[-3000:]}")


def sim(args: argparse.Namespace, tmp: Path) -> None:
    print(f"## Simulated sessions (tmscal simulate --arm ur5e, realistic errors, 40 Eq. 14 "
          f"poses of 10 samples, seeds {args.first_seed}..{args.first_seed + args.seeds - 1}): "
          "5-fold cross-validated e_t (mm)\n")
    print(f"  {'noise (tracker mm, robot mm/°)':32}{'QR24 raw':>10}{'QR36 rigid':>12}"
          f"{'estimated arm (ml)':>20}")
    for sigma in (0.05, 0.1):
        e = {"qr24": [], "qr36": [], "ml": []}
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            out = tmp / f"sim-{sigma}-{seed}.jsonl"
            _tmscal("simulate", "-o", out, "--arm", "ur5e", "--poses", 40, "--seed", seed,
                    "--samples", 10, "--fiducial-sigma", sigma, "--robot-rot-sigma", sigma,
                    "--robot-trans-sigma", sigma)
            s = read_session(out)
            for m, kw in (("qr24", {}), ("qr36", {"orthonormal": True}),
                          ("ml", {"kinematics": "estimate"})):
                e[m].append(solve(s, method=m, **kw).errors["e_t_mm"])
        print(f"  {f'{sigma:g} / {sigma:g} / {sigma:g}':32}{np.mean(e['qr24']):>10.4f}"
              f"{np.mean(e['qr36']):>12.4f}{np.mean(e['ml']):>20.4f}")
        record("kinematics", {(f"sim_{m}_e_t_mm_sigma{sigma:g}".replace(".", "_")
                               + _tag(args)): np.mean(v)
                              for m, v in e.items()})
    print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=1, help="the first mock/simulate seed")
    ap.add_argument("--noise-scale", type=float, default=1.0,
                    help="factor on the mock rig's fiducial and robot noise (part 1 and 2)")
    ap.add_argument("--poses", type=int, default=40, help="poses of part 1's sessions")
    ap.add_argument("--ladder", type=lambda s: [int(x) for x in s.split(",")],
                    default=[10, 15, 20, 30, 40], help="pose counts of part 2")
    ap.add_argument("--samples", type=int, default=100, help="tracker frames per pose")
    ap.add_argument("--wrench-poses", type=int, default=30, help="poses of part 4's sessions")
    ap.add_argument("--ft-samples", type=int, default=50,
                    help="wrench readings averaged per pose in part 4")
    ap.add_argument("--skip-sim", action="store_true")
    ap.add_argument("--skip-rig", action="store_true")
    ap.add_argument("--skip-wrench", action="store_true")
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    with tempfile.TemporaryDirectory(prefix="tmscal-kin-bench-") as d:
        if not args.skip_rig:
            rig(args, Path(d))
        if not args.skip_wrench:
            wrench(args, Path(d))
        if not args.skip_sim:
            sim(args, Path(d))


if __name__ == "__main__":
    main()
