"""End to end on the mocks (docs/safety.md, "Where it was calibrated"): with ``plan.start:
current`` the P0 of a run is wherever the arm was left, so on one rig a second session is
centred on the first one's last pose; ``acquire --calib CAL`` runs around the calibration's P0
instead, the daily check warns (with the distance) about a session made elsewhere and not about
one made there, and ``robot --calib CAL --move-to p0`` takes the arm back even from where an
ordinary jog to P0 is refused. One mock process serves every session, so the arm stays where
each run left it, as on a real rig; every device is reached through its real driver and wire
protocol."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.geometry import angle_between, denso_p_from_matrix, make_pose
from tmscal.mocks.launch import spawn_mock_rig
from tmscal.session import read_session
from tmscal.sim import TMS_RIG_P0


def _run(*args: object) -> tuple[int, str]:
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.output


def _rz(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return make_pose(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), [0.0, 0.0, 0.0])


def _pose_arg(T: np.ndarray) -> str:
    return ",".join(f"{v:.6f}" for v in denso_p_from_matrix(T))


def _p0(path) -> np.ndarray:
    return np.asarray(read_session(path).header["plan"]["p0"], dtype=float)


@pytest.mark.e2e
def test_p0_is_kept_across_sessions_and_the_arm_goes_back(tmp_path, mock_config) -> None:
    cfg = mock_config("mock-ur-polaris.yaml", plan={"poses": 15, "seed": 1},
                      sampling={"samples": 8})
    cal = tmp_path / "cal.yaml"
    with spawn_mock_rig(cfg, transport="pty") as mp:
        ep = ["--tracker-port", mp.endpoints["tracker"], "--robot-host", mp.endpoints["robot"]]
        rob = ["--robot-host", mp.endpoints["robot"]]
        code, out = _run("acquire", cfg, "-o", tmp_path / "s1.jsonl", *ep)
        assert code == 0, out
        code, out = _run("solve", tmp_path / "s1.jsonl", "-o", cal, "--folds", 2)
        assert code == 0, out
        p0 = _p0(tmp_path / "s1.jsonl")
        # the mock's flange starts at the built-in rig's P0: the calibration was made there
        assert np.linalg.norm(p0[:3, 3] - TMS_RIG_P0[:3, 3]) < 0.5

        # plan.start: current without --calib: P0 walks to where the last run ended
        code, out = _run("acquire", cfg, "-o", tmp_path / "s2.jsonl", "--poses", 5, *ep)
        assert code == 0 and "give --calib CAL" in out, out
        walked = _p0(tmp_path / "s2.jsonl")
        last = read_session(tmp_path / "s1.jsonl").poses[-1].commanded
        assert np.linalg.norm(walked[:3, 3] - last[:3, 3]) < 0.5
        code, out = _run("solve", tmp_path / "s2.jsonl", "--calib", cal, "--json")
        p = json.loads(out)["p0"]
        dist = float(np.linalg.norm(walked[:3, 3] - p0[:3, 3]))
        assert p["same"] is False and abs(p["mm"] - dist) < 1e-6, p
        code, out = _run("solve", tmp_path / "s2.jsonl", "--calib", cal)
        assert "WARNING: this session's P0 is" in out and f"{dist:.1f} mm" in out, out

        # --calib: the run is centred on the calibration's P0 although the arm is elsewhere
        code, out = _run("acquire", cfg, "-o", tmp_path / "s3.jsonl", "--poses", 5,
                         "--calib", cal, *ep)
        assert code == 0, out
        assert np.abs(_p0(tmp_path / "s3.jsonl") - p0).max() < 1e-9
        code, out = _run("solve", tmp_path / "s3.jsonl", "--calib", cal, "--json")
        assert json.loads(out)["p0"]["same"] is True
        code, out = _run("solve", tmp_path / "s3.jsonl", "--calib", cal)
        assert "P0 is" not in out, out

        # jog away 30° about the tool axis in two steps the envelope allows (20° each)
        code, out = _run("robot", cfg, *rob, "--calib", cal, "--move-to", "p0", "--yes")
        assert code == 0, out
        for deg in (15, 30):
            code, out = _run("robot", cfg, *rob, "--move-to", _pose_arg(p0 @ _rz(deg)),
                             "--yes")
            assert code == 0, out
        # an acquire around the calibration's P0 refuses to start from there, naming the way
        code, out = _run("acquire", cfg, "-o", tmp_path / "s4.jsonl", "--poses", 3,
                         "--calib", cal, *ep)
        assert code != 0 and "--move-to p0" in out and not (tmp_path / "s4.jsonl").exists()
        # an ordinary jog to P0 is refused (30° > the envelope's 20° around the current pose)
        code, out = _run("robot", cfg, *rob, "--move-to", _pose_arg(p0), "--yes")
        assert code != 0 and "rotation" in out, out
        # going back to the calibration's P0 is always allowed inside the box
        code, out = _run("robot", cfg, *rob, "--calib", cal, "--move-to", "p0", "--yes")
        assert code == 0, out
        code, out = _run("acquire", cfg, "-o", tmp_path / "s4.jsonl", "--poses", 3,
                         "--calib", cal, *ep)
        assert code == 0, out
        first = read_session(tmp_path / "s4.jsonl").poses[0]
        assert np.degrees(angle_between(first.commanded, p0)) <= 10.0 + 1e-6
