"""Time to calibrate: adaptive acquisition on the mock rig in real time, beside fixed protocols.

    .venv/bin/python benchmarks/time_to_calibrate.py [--seeds 5] [--config C] [--target-mm T]

For each rig seed (``mock.seed`` 0…seeds−1, a temporary copy of the config; default
``configs/mock-ur-polaris-realtime.yaml``: mock UR + mock Polaris on the REAL-TIME clock, with
trapezoidal motion and the coil's settling oscillation), on the same rig:

* adaptive: ``acquire --adaptive`` with the default settings (target 0.05 mm at 95 %) through
  the real drivers and wire protocols. Robot time = moving + settling + sampling, measured
  from the first move to the last sample (the computing between poses is shown apart, as
  wall time); the true coil-placement error of the calibration it stops with (ml) against
  the mock rig's truth, mean over the prediction's region (the plan's first ``region`` poses);
* Wang et al. (2018)'s protocol, 500 poses × 100 samples after a 1 s settle, QR36;
* 10, 20 and 50 poses drawn at random from the same candidate pool, QR36, with the config's
  sampling (samples, then a 1 s settle).

The fixed protocols are not waited out: their robot time is the motion model
(``tmscal.motion``, the config's speed and acceleration caps, from P0 through every pose)
+ settle + samples / frame rate per pose, and their error is measured on a simulation of the
same rig (``tmscal.sim.SimRig`` with the mock's truth and noise, the samples averaged), over
the same region. Prints one row per seed and the means, minima and maxima over the seeds (and
records them, ``benchmarks/figures.py``). Goal: adaptive ≤ 60 s robot time
with a true error ≤ 0.05 mm, mean over the seeds. Takes several minutes (real time).
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from figures import record

from tmscal.acquisition.adaptive_run import acquire_adaptive, settings_for
from tmscal.calib import solve
from tmscal.calib.prediction import true_coil_error
from tmscal.config import load_config
from tmscal.geometry import pose_mean
from tmscal.mocks.launch import build_sim_rig, spawn_mock_rig
from tmscal.motion import move_duration
from tmscal.poses import PlanSpec
from tmscal.sim import SimRig

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
WANG = (500, 100, 1.0)  # poses, samples, settle (s): the protocol of Wang et al. (2018)
RANDOM_K = (10, 20, 50)


def seeded_config(base: Path, tmp: Path, seed: int) -> Path:
    """A copy of ``base`` with ``mock.seed`` = seed, ROM paths absolute, and a loopback
    address of its own for the UR mock (its ports are fixed per address)."""
    data = yaml.safe_load(base.read_text())
    data["tracker"]["tools"] = {k: str((base.parent / v).resolve())
                                for k, v in data["tracker"]["tools"].items()}
    data["mock"]["seed"] = seed
    if data["robot"]["driver"] == "ur":
        data["robot"]["host"] = f"127.0.0.{200 + seed}"
    p = tmp / f"rig-seed{seed}.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def run_adaptive(cfg_path: Path, out: Path, target_mm: float) -> dict:
    """The adaptive run on the mock rig (mocks in a child process); robot time by phase, wall
    time, poses, predicted and true coil-placement error (mm)."""
    cfg = load_config(cfg_path)
    truth = build_sim_rig(cfg).truth
    settings = settings_for(cfg, target_mm=target_mm)
    with spawn_mock_rig(cfg_path, transport="tcp") as mp:
        host, _, port = mp.endpoints["robot"].partition(":")
        t0 = time.monotonic()
        res = acquire_adaptive(cfg, out, settings=settings, tracker_port=mp.endpoints["tracker"],
                               robot_host=host, robot_port=int(port) if port else None)
        wall = time.monotonic() - t0
    region = PlanSpec.from_config(cfg.plan, _p0(cfg), settings.region).poses()
    true = true_coil_error(res.prediction.calibration, truth.Y, truth.Z, region)
    return {"poses": res.recorded + res.skipped, "robot": res.robot_time_s, "wall_s": wall,
            "predicted_mm": res.prediction.coil_mm, "true_mm": true, "stop": res.stop}


def _p0(cfg) -> np.ndarray:
    """P0 of the mock rig: where its flange starts (the plan's start is "current")."""
    return build_sim_rig(cfg).flange.copy() if isinstance(cfg.plan.start, str) \
        else np.asarray(cfg.plan.start, dtype=float)


def model_time_s(poses: np.ndarray, p0: np.ndarray, cfg, samples: int, settle_s: float
                 ) -> float:
    """Robot time (s) of a fixed protocol by the motion model: the trapezoidal moves from P0
    through every pose at the config's speed and acceleration caps, + settle + samples at
    the tracker's frame rate per pose."""
    path = np.concatenate([p0[None], poses])
    v, a = cfg.robot.speed_mm_s, cfg.robot.accel_mm_s2
    moving = sum(move_duration(path[i], path[i + 1], v, a) for i in range(len(poses)))
    return moving + len(poses) * (settle_s + samples / cfg.tracker.frame_rate_hz)


def simulated_error(cfg, poses: np.ndarray, samples: int, region: np.ndarray,
                    seed: int) -> float:
    """True coil-placement error (mm, mean over the region) of QR36 on ``poses`` measured on
    a simulation of the mock rig (its truth and noise), ``samples`` frames averaged per pose."""
    ref = build_sim_rig(cfg)
    rig = SimRig(ref.truth, noise=ref.noise, rng=np.random.default_rng([seed, 1]),
                 start=ref.flange)
    A, B, C = [], [], []
    for P in poses:
        rig.move_flange(P)
        A.append(rig.reported_flange())
        B.append(pose_mean(rig.observe("marker", samples)))
        C.append(pose_mean(rig.observe("probe", samples)))
    cal = solve(np.stack(A), np.stack(B), np.stack(C), method="qr36")
    return true_coil_error(cal, ref.truth.Y, ref.truth.Z, region)


def fixed_protocols(cfg_path: Path, seed: int) -> dict[str, tuple[float, float]]:
    """{protocol: (robot time s, true error mm)} for Wang et al.'s protocol and random k."""
    cfg = load_config(cfg_path)
    settings = settings_for(cfg)
    p0 = _p0(cfg)
    pool = PlanSpec.from_config(cfg.plan, p0, settings.pool).poses()
    region = pool[:settings.region]
    n, samples, settle = WANG
    plan = PlanSpec.from_config(cfg.plan, p0, n).poses()
    out = {"wang": (model_time_s(plan, p0, cfg, samples, settle),
                    simulated_error(cfg, plan, samples, region, seed))}
    rng = np.random.default_rng([seed, 2])
    for k in RANDOM_K:
        poses = pool[rng.choice(len(pool), k, replace=False)]
        out[f"random{k}"] = (model_time_s(poses, p0, cfg, cfg.sampling.samples, 1.0),
                             simulated_error(cfg, poses, cfg.sampling.samples, region, seed))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--config", type=Path, default=CONFIGS / "mock-ur-polaris-realtime.yaml")
    ap.add_argument("--target-mm", type=float, default=0.05)
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    cols = ["adaptive"] + ["wang"] + [f"random{k}" for k in RANDOM_K]
    print(f"config {args.config}, {args.seeds} rig seeds, target {args.target_mm} mm at 95 %")
    print(f"{'seed':>4} {'poses':>5} {'moving':>7} {'settle':>7} {'sample':>7} {'robot s':>8} "
          f"{'wall s':>7} {'pred mm':>8} {'true mm':>8} | "
          + " | ".join(f"{c:>8} s {'mm':>6}" for c in cols[1:]))
    rows = []
    with tempfile.TemporaryDirectory(prefix="tmscal-ttc-") as tmp:
        for seed in range(args.seeds):
            cfg_path = seeded_config(args.config, Path(tmp), seed)
            a = run_adaptive(cfg_path, Path(tmp) / f"s{seed}.jsonl", args.target_mm)
            f = fixed_protocols(cfg_path, seed)
            r = a["robot"]
            print(f"{seed:>4} {a['poses']:>5} {r['moving']:>7.1f} {r['settling']:>7.1f} "
                  f"{r['sampling']:>7.1f} {r['total']:>8.1f} {a['wall_s']:>7.1f} "
                  f"{a['predicted_mm']:>8.4f} {a['true_mm']:>8.4f} | "
                  + " | ".join(f"{f[c][0]:>10.0f} {f[c][1]:>6.3f}" for c in cols[1:]),
                  flush=True)
            rows.append([a["poses"], r["moving"], r["settling"], r["sampling"], r["total"],
                         a["wall_s"], a["predicted_mm"], a["true_mm"]]
                        + [x for c in cols[1:] for x in f[c]])
    stats = {"mean": np.mean(rows, axis=0), "min": np.min(rows, axis=0),
             "max": np.max(rows, axis=0)}
    for name, m in stats.items():
        print(f"{name:>4} {m[0]:>5.1f} {m[1]:>7.1f} {m[2]:>7.1f} {m[3]:>7.1f} {m[4]:>8.1f} "
              f"{m[5]:>7.1f} {m[6]:>8.4f} {m[7]:>8.4f} | "
              + " | ".join(f"{m[8 + 2 * i]:>10.0f} {m[9 + 2 * i]:>6.3f}"
                           for i in range(len(cols) - 1)))
    m = stats["mean"]
    fig: dict[str, float] = {"seeds": args.seeds}
    for name, v in stats.items():
        fig.update({f"adaptive_poses_{name}": round(v[0], 1),
                    f"adaptive_robot_s_{name}": round(v[4], 1),
                    f"adaptive_true_mm_{name}": round(v[7], 4)})
    fig.update({"adaptive_moving_s_mean": round(m[1], 1),
                "adaptive_settling_s_mean": round(m[2], 1),
                "adaptive_sampling_s_mean": round(m[3], 1),
                "adaptive_wall_s_mean": round(m[5], 1),
                "adaptive_predicted_mm_mean": round(m[6], 4)})
    for i, c in enumerate(cols[1:]):
        fig.update({f"{c}_robot_s_mean": round(m[8 + 2 * i]),
                    f"{c}_true_mm_mean": round(m[9 + 2 * i], 3)})
    record("time_to_calibrate", fig)
    print(f"goal: adaptive robot time ≤ 60 s (mean {m[4]:.1f} s) and true error ≤ 0.05 mm "
          f"(mean {m[7]:.4f} mm); Wang et al.'s protocol takes {m[8] / 60:.1f} min of robot "
          f"time for {m[9]:.3f} mm")


if __name__ == "__main__":
    main()
