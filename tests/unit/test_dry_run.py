"""``tmscal acquire --dry-run`` shows the run that will happen and checks the tracker section
offline: a Vega address without ``socket://``, a YAML file given as a ROM and a frame rate no
NDI tracker has are refused naming the file and the key; an adaptive run is its bootstrap, its
pose limit and its robot time at most, not its 1,000 candidates; with ``plan.start: current``
and no robot it says what it could not check. No device answers in these tests: the robot's
address is a loopback address of the test's own where nothing listens (a refusal, at once),
and the tracker is never opened."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tests.rigs import TOOLS_DIR, write_config
from tmscal.acquisition.adaptive_run import settings_for
from tmscal.acquisition.dryrun import dry_run
from tmscal.cli import main
from tmscal.config import load_config
from tmscal.motion import move_duration

MARKER = str(TOOLS_DIR / "marker-8700340.rom")


def _acquire(cfg: Path, *args: str) -> tuple[int, str]:
    r = CliRunner().invoke(main, ["acquire", str(cfg), "-o", str(cfg.with_suffix(".jsonl")),
                                  "--dry-run", *args])
    return r.exit_code, r.output


def _rig(tmp_path: Path, **changes) -> Path:
    """The UR + Polaris demo config; its robot at an address where nothing listens."""
    return write_config(tmp_path, "mock-ur-polaris.yaml", **changes)


def test_a_vega_address_without_socket_scheme_is_refused_before_anything(tmp_path) -> None:
    cfg = _rig(tmp_path, tracker={"port": "192.168.1.10:8765"})
    code, out = _acquire(cfg)
    assert code == 1, out
    assert re.match(rf"error: {re.escape(str(cfg))}, line \d+: key 'tracker.port': "
                    r"'192\.168\.1\.10:8765': a network address without socket://", out), out
    assert "socket://192.168.1.10:8765" in out and "No such file" not in out
    assert len(out.strip().splitlines()) == 1


@pytest.mark.parametrize("content", ["name: my rig\nrobot: {driver: ur}\n",  # a YAML file
                                     "NDI marker, see the manual\n"])        # text, NDI first
def test_a_text_file_given_as_a_rom_is_refused_naming_the_file_and_key(tmp_path,
                                                                       content) -> None:
    rom = tmp_path / "probe.rom"
    rom.write_text(content)
    cfg = _rig(tmp_path, tracker={"tools": {"marker": MARKER, "probe": str(rom)}})
    load_config(cfg)  # the file exists: loading the config passes, as before
    code, out = _acquire(cfg)
    assert code == 1, out
    assert re.match(rf"error: {re.escape(str(cfg))}, line \d+: key 'tracker.tools.probe': "
                    rf"ROM file {re.escape(str(rom))}: not an NDI tool definition", out), out


def test_a_frame_rate_no_ndi_tracker_has_is_refused(tmp_path) -> None:
    code, out = _acquire(_rig(tmp_path, tracker={"frame_rate_hz": 600}))
    assert code == 1 and "key 'tracker.frame_rate_hz': 600 Hz is outside" in out, out
    assert "20…400 Hz" in out


def test_start_current_without_the_robot_checks_what_it_can_and_says_what_not(tmp_path
                                                                              ) -> None:
    cfg = _rig(tmp_path)
    code, out = _acquire(cfg, "--poses", "30")
    assert code == 0, out
    assert "tracker (checked offline; nothing opened):" in out
    assert "tool marker: " in out and "an NDI tool definition (600 bytes)" in out
    assert "frame rate 60 Hz" in out
    assert "plan eq14: 30 poses" in out and "not known without the robot" in out
    assert re.search(r"  robot: did not answer: ur [\d.]+: cannot connect", out), out
    assert ("not checked without the robot: the workspace box for the flange and the coil's "
            "points, and the paths between the poses") in out
    assert "workspace box (safety)" not in out  # no base-frame extents around a stand-in P0
    assert "every pose within the offset and rotation limits from P0" in out
    # the limits from P0 are still judged: a plan beyond max_offset_mm is refused offline
    code, out = _acquire(_rig(tmp_path, plan={"radius_mm": 150}), "--poses", "30")
    assert code == 1 and "leaves the safety envelope" in out and "offset" in out, out


def test_the_adaptive_dry_run_is_the_run_not_its_candidates(tmp_path) -> None:
    """The 1,000-pose pool is what the run chooses from; the run measures its bootstrap and
    then at most max_poses poses, and its robot time is at most max_poses × (the longest
    move + a pose's settling and sampling)."""
    cfg = _rig(tmp_path, sampling={"settle_s": 0.5})
    code, out = _acquire(cfg, "--adaptive")
    assert code == 0, out
    assert ("4 well-spread bootstrap poses, then one chosen pose at a time; stops when the "
            "predicted coil-placement error is ≤ 0.05 mm at 95 %, at most 40 poses "
            "(max_poses)") in out
    assert "the 1000 candidates (adaptive.pool)" in out
    assert "1000 poses" not in out and "estimated duration" not in out
    full = float(re.search(r"robot time at most ([\d.]+) min", out).group(1))
    code, out = _acquire(cfg, "--adaptive", "--max-poses", "10")
    assert code == 0 and "at most 10 poses (max_poses)" in out, out
    assert float(re.search(r"robot time at most ([\d.]+) min", out).group(1)) == \
        pytest.approx(full / 4, abs=0.1)


def test_the_adaptive_robot_time_bounds_every_move_between_candidates(tmp_path) -> None:
    cfg = load_config(_rig(tmp_path, plan={"start": {"xyz_mm": [500, 0, 400],
                                                     "rpy_deg": [180, 0, 0]}},
                           sampling={"settle_s": 0.5, "samples": 60}))
    settings = settings_for(cfg)
    d = dry_run(cfg, adaptive=settings)
    a = d.adaptive
    assert a is not None and d.p0_known and d.spec.n == settings.pool == 1000
    assert (a.max_poses, a.bootstrap) == (40, 4)
    assert a.per_pose_s == pytest.approx(0.5 + 60 / 60.0)  # settle_s + samples / rate
    assert a.robot_time_max_s == pytest.approx(40 * (a.longest_move_s + a.per_pose_s))
    pool = d.spec.poses()
    rng = np.random.default_rng(0)
    starts = np.concatenate([pool[rng.integers(0, len(pool), 300)], [d.spec.p0]])
    ends = pool[rng.integers(0, len(pool), len(starts))]
    far = pool[np.argmax(np.linalg.norm(pool[:, :3, 3] - d.spec.p0[:3, 3], axis=1))]
    worst = max(move_duration(s, e, cfg.robot.speed_mm_s, cfg.robot.accel_mm_s2)
                for s, e in [*zip(starts, ends), (d.spec.p0, far)])
    assert worst <= a.longest_move_s  # a straight move between candidates
    # and a move split through P0: both legs
    assert 2 * move_duration(d.spec.p0, far, cfg.robot.speed_mm_s,
                             cfg.robot.accel_mm_s2) <= a.longest_move_s + 1e-9
