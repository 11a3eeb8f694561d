"""Loop closure on the mock rig: the coil-placement error of the one-step hand/eye calibration
before and after kinematic self-calibration (docs/selfcal.md, "Running it").

    .venv/bin/python benchmarks/selfcal_rig.py [--errors paper,all] [--poses 100] [--k 60]

For each protocol of hidden kinematic errors (``mock.kinematics.errors``: ``paper``, uniform
±2 mm / ±1° on the parameters the gravity wrench identifies, as Joubair et al. 2016
simulate; ``all``, on every geometric parameter), on ``configs/mock-ur-ati.yaml`` (mock UR5e,
mock ATI Net F/T, mock Polaris, fast clock; a temporary copy on its own loopback address):

1. ``tmscal acquire``: a hand/eye session of ``--poses`` Eq. 14 poses (Wang et al. 2018)
   through the real drivers, joints recorded;
2. QR36 and ml on it, the robot poses A as the controller reported them (its NOMINAL model);
3. ``tmscal selfcal acquire`` (``--k`` configurations) and ``tmscal selfcal identify``;
4. QR36 and ml again with A recomputed from the recorded joints by the identified model
   (what ``tmscal solve --kinematics`` does), and, as the ceiling, by the true model.

How the true coil placement is computed when the robot's own kinematics are wrong. A target
is a coil pose in the tracker frame, T (tracker ← probe). A calibration (Y, Z) turns it into a
flange command A_cmd = Z · T · Y⁻¹ (base ← flange; ``Calibration.placement``: T undistorted
first when ml found a tracker distortion; orthonormalised, as ``calib.metrics`` does). The
robot reaches a flange pose through joints: q solves the kinematic model in use for A_cmd —
the controller's nominal model before self-calibration, the identified model after it (the
command sent to the controller is then the nominal pose at that q, so that its own inverse
kinematics land at q). The arm really goes to the TRUE model's flange at q, and the coil
really is at Z_true⁻¹ · A_true(q) · Y_true. The placement error is the distance between that
coil centre and T's (mm), and the angle between their orientations (deg). The targets are
200 coil poses the true rig produces from flange poses of another Eq. 14 plan (seed 2) around
the same P0: the workspace the calibration was made for. The "arm TCP" column is the mean
position error of the model in use against the true arm over the same joints (the arm's own
absolute error, without any hand/eye calibration).

Prints one table per protocol. Takes about a minute per protocol on this machine.
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml
from figures import record

from tmscal.acquisition.run import acquire
from tmscal.calib import solve
from tmscal.config import load_config
from tmscal.formats.kinfile import load_arm
from tmscal.geometry import invert
from tmscal.mocks.launch import build_sim_rig, spawn_mock_rig
from tmscal.poses import make_plan
from tmscal.session import read_session
from tmscal.sim.arm import reach
from tmscal.solving.solve import with_kinematics

CONFIG = Path(__file__).resolve().parents[1] / "tmscal" / "data" / "configs" / "mock-ur-ati.yaml"
ROBOT_HOST = "127.0.0.185"   # a loopback address of its own (ur_rtde's ports are fixed)
METHODS = ("qr36", "ml")


def _config(tmp: Path, errors: str, poses: int) -> Path:
    data = yaml.safe_load(CONFIG.read_text())
    data["tracker"]["tools"] = {k: str(CONFIG.parent / v)
                                for k, v in data["tracker"]["tools"].items()}
    data["robot"]["host"] = ROBOT_HOST
    data["ft"]["port"] = 0
    data["plan"]["poses"] = poses
    data["sampling"]["samples"] = 30
    data["mock"]["kinematics"] = {"arm": "ur5e", "errors": errors}
    p = tmp / f"rig-{errors}.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _tmscal(*args: object) -> str:
    r = subprocess.run([sys.executable, "-m", "tmscal.cli", *map(str, args)],
                       capture_output=True, text=True, timeout=1200)
    if r.returncode != 0:
        raise SystemExit(f"tmscal {' '.join(map(str, args))} failed:\n{r.stderr[-3000:]}")
    return r.stdout


def _targets(rig, p0: np.ndarray, n: int = 200) -> np.ndarray:
    """Coil poses (n, 4, 4) tracker ← probe, mm, that the true rig produces from the flange
    poses of an Eq. 14 plan (seed 2) around ``p0``."""
    P = make_plan("eq14", p0, n, 2, 100.0, 10.0)
    t = rig.truth
    return np.einsum("ij,njk,kl->nil", invert(t.Z), P, t.Y)


def _placement(pair, model, cal, truth, targets: np.ndarray) -> tuple[float, float, float, float]:
    """(mean mm, max mm, mean deg, arm TCP mean mm) of the coil placed at ``targets`` with
    calibration ``cal`` commanded through kinematic model ``model`` (module docstring)."""
    from tmscal.geometry import angle_between, orthonormalize

    pos, ang, tcp = [], [], []
    q_now = np.array(pair.home_q)
    cmd, Y, Z = cal.placement(targets)   # undistorted targets when ml found a distortion
    for T, N in zip(targets, cmd, strict=True):
        A_cmd = orthonormalize(Z @ N @ invert(Y))
        q = reach(model, model.base @ invert(pair.mount) @ A_cmd, q_now, pair.home_q)
        if q is None:
            continue
        q_now = q
        coil = invert(truth.Z) @ pair.actual(q) @ truth.Y
        pos.append(np.linalg.norm(coil[:3, 3] - T[:3, 3]))
        ang.append(float(np.degrees(angle_between(coil, T))))
        tcp.append(np.linalg.norm(pair.actual(q)[:3, 3] - pair.flange(model, q)[:3, 3]))
    e = np.array(pos)
    return float(e.mean()), float(e.max()), float(np.mean(ang)), float(np.mean(tcp))


def run(errors: str, poses: int, k: int) -> list[tuple[str, str, tuple[float, ...]]]:
    with tempfile.TemporaryDirectory(prefix="tmscal-selfcal-rig-") as d:
        tmp = Path(d)
        cfg_path = _config(tmp, errors, poses)
        cfg = load_config(cfg_path)
        s_path, sc_path, kin = tmp / "s.jsonl", tmp / "sc.jsonl", tmp / "kin.yaml"
        with spawn_mock_rig(cfg_path, transport="tcp") as mp:
            ep = mp.endpoints
            # the hand/eye run reads the wrist sensor too: point the config at the mock's
            host, _, port = ep["ft"].rpartition(":")
            data = yaml.safe_load(cfg_path.read_text())
            data["ft"].update(host=host, port=int(port))
            he_path = tmp / "rig-handeye.yaml"
            he_path.write_text(yaml.safe_dump(data))
            acquire(load_config(he_path), s_path, tracker_port=ep["tracker"],
                    robot_host=ep["robot"])
            _tmscal("selfcal", "acquire", cfg_path, "-o", sc_path, "--k", k,
                    "--robot-host", ep["robot"], "--ft-host", ep["ft"])
        # the paper's errors sit on the columns the fit keeps: its kept-column fit, as the
        # paper reports it; errors on every parameter: the default MAP arm, which does not
        # depend on the kept columns (docs/selfcal.md, "Running it")
        form = "kept" if errors == "paper" else "map"
        print(_tmscal("selfcal", "identify", sc_path, "-o", kin, "--form", form
                      ).splitlines()[0])
        rig = build_sim_rig(cfg)   # the child built the same rig from the same config
        pair, truth = rig.arm, rig.truth
        session = read_session(s_path)
        targets = _targets(rig, np.asarray(session.header["plan"]["p0"]))
        rows = []
        for label, model in (("nominal (controller)", pair.nominal),
                             ("self-calibrated", load_arm(kin)), ("true (ceiling)", pair.true)):
            s = session if model is pair.nominal else with_kinematics(session, model)
            A, B, C, _ = s.arrays(need_probe=True)
            for method in METHODS:
                cal = solve(A, B, C, method=method)
                rows.append((label, method, _placement(pair, model, cal, truth, targets)))
        return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--errors", default="paper,all", help="protocols, comma-separated")
    ap.add_argument("--poses", type=int, default=100, help="hand/eye poses (Eq. 14)")
    ap.add_argument("--k", type=int, default=60, help="self-calibration configurations")
    a = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    for errors in a.errors.split(","):
        print(f"\nhidden kinematic errors: {errors} (mock UR5e, seed 7); {a.poses} hand/eye "
              f"poses, {a.k} self-calibration configurations")
        rows = run(errors, a.poses, a.k)
        print(f"  {'kinematics of A and of the command':<36}{'method':<7}"
              f"{'coil mean mm':>13}{'max mm':>9}{'mean deg':>10}{'arm TCP mm':>12}")
        fig: dict[str, float] = {}
        for label, method, (mean, mx, deg, tcp) in rows:
            print(f"  {label:<36}{method:<7}{mean:>13.3f}{mx:>9.3f}{deg:>10.3f}{tcp:>12.3f}")
            key = f"{errors}_{label.split()[0].replace('-', '_')}_{method}"
            fig.update({f"{key}_mean_mm": round(mean, 3), f"{key}_max_mm": round(mx, 3),
                        f"{key}_mean_deg": round(deg, 3), f"{key}_arm_tcp_mm": round(tcp, 3)})
        record("selfcal_rig", fig)


if __name__ == "__main__":
    main()
