"""What the user sees during a run, end to end: `tmscal acquire` and `tmscal track` in a child
process (a pipe, or a pty of 80 columns) against the DENSO and Polaris mocks served from this
process over loopback TCP, through the real drivers and wire protocols. A mock fault
(``mock.tracker.faults.missing_fraction``) hides tools, so that poses are skipped."""

from __future__ import annotations

import fcntl
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios

import pytest

from tmscal.config import load_config
from tmscal.mocks.launch import start_mock_rig
from tmscal.session import read_session

from ..rigs import REPO, point_config

_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def _rig(mock_config, missing: float = 0.0, run: dict | None = None):
    cfg = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                      sampling={"samples": 10},
                      run={"retries": 0, **(run or {})},
                      mock={"tracker": {"model": "spectra",
                                        "faults": {"missing_fraction": missing}}})
    return cfg


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "tmscal.cli", *args]


def _env(**kw: str) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO), **kw}


def _run_in_pty(cmd: list[str], columns: int = 80, timeout_s: float = 120.0) -> tuple[int, str]:
    """Run ``cmd`` with stdin/stdout/stderr on a new pty of ``columns`` columns; its output
    (both streams) and exit status."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, columns, 0, 0))
    p = subprocess.Popen(cmd, stdin=slave, stdout=slave, stderr=slave, close_fds=True,
                         env=_env(COLUMNS=str(columns)), cwd=REPO)
    os.close(slave)
    out = b""
    try:
        while True:
            ready, _, _ = select.select([master], [], [], timeout_s)  # a hang guard only
            assert ready, "no output from the child for too long"
            try:
                chunk = os.read(master, 65536)
            except OSError:  # EIO: the child closed the pty
                break
            if not chunk:
                break
            out += chunk
    finally:
        os.close(master)
    return p.wait(timeout=timeout_s), out.decode("utf-8", "replace")


def _screen_lines(text: str) -> list[str]:
    """What a terminal shows, line by line: escapes removed, split at \\r and \\n."""
    return [s for s in re.split(r"[\r\n]", _ANSI.sub("", text)) if s]


def _progress_lines(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if ln.startswith("pose ")]


@pytest.mark.e2e
def test_plain_progress_one_line_per_pose_counts_skips_and_warns_once(tmp_path, mock_config):
    # 20 % of tool reports missing: with 10 samples and min_share 0.8 some poses fail twice
    cfg = _rig(mock_config, missing=0.2,
               run={"warn_skip_share": 0.1, "stop_skip_share": 1.0, "skip_window": 20})
    out = tmp_path / "s.jsonl"
    with start_mock_rig(load_config(cfg), tracker_transport="tcp") as mr:
        pointed = point_config(cfg, mr.endpoints)
        r = subprocess.run(_cli("acquire", str(pointed), "-o", str(out), "--poses", "20"),
                           capture_output=True, text=True, timeout=240, env=_env(), cwd=REPO)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "\r" not in r.stderr
    poses = read_session(out).poses
    skipped = [p for p in poses if p.skipped]
    assert len(skipped) > 2, "the fault should have made this run skip poses"
    lines = _progress_lines(r.stderr)
    assert [ln.split()[1] for ln in lines] == [f"{k}/20" for k in range(1, 21)]
    for ln, rec in zip(lines, poses):
        k = sum(p.skipped is not None for p in poses if p.index <= rec.index)
        if rec.skipped:  # the whole reason, uncut: how often each tool was seen, min_share
            assert ln.endswith(f"skipped ({k} so far): {rec.skipped}"), (ln, rec.skipped)
            assert re.search(r"seen in \d+ of 10 frames.*, below min_share 0\.8", ln), ln
        else:
            assert len(ln) <= 80, ln
            assert f"skipped {k}" in ln, ln
            sp = rec.spread["marker"]
            assert f"marker spread {sp['trans_mm']:.3f} mm / {sp['rot_deg']:.3f}°" in ln
    # one warning, right after the pose whose skip took the count past 10 % of 20 (2)
    warnings = [i for i, ln in enumerate(r.stderr.splitlines()) if "warn_skip_share" in ln]
    assert len(warnings) == 1, r.stderr
    third = skipped[2].index
    all_lines = r.stderr.splitlines()
    assert all_lines[warnings[0] - 1] == lines[third]
    # the tools were seen, in too few frames: the warning says so, with min_share and the
    # counts of the last such pose, not "not seen"
    warning = all_lines[warnings[0]]
    assert "seen in too few frames (below min_share 0.8) in" in warning, warning
    assert re.search(r"\(the last: \w+ \d+ of 10 frames", warning), warning
    assert "not seen" not in warning, warning


@pytest.mark.e2e
def test_run_that_skips_too_many_poses_stops_resumably_naming_the_reason(tmp_path,
                                                                         mock_config):
    cfg = _rig(mock_config, missing=1.0,
               run={"warn_skip_share": 0.25, "stop_skip_share": 0.5, "skip_window": 4})
    out = tmp_path / "s.jsonl"
    with start_mock_rig(load_config(cfg), tracker_transport="tcp") as mr:
        pointed = point_config(cfg, mr.endpoints)
        r = subprocess.run(_cli("acquire", str(pointed), "-o", str(out), "--poses", "10"),
                           capture_output=True, text=True, timeout=240, env=_env(), cwd=REPO)
        assert r.returncode == 1, r.stderr[-2000:]
        # every tool hidden: poses 0, 1, 2 skipped; 2 of 4 > 25 % warns, 3 of 4 > 50 % stops
        assert [p.index for p in read_session(out).poses if p.skipped] == [0, 1, 2]
        err = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
        assert len(err) == 1, r.stderr
        assert ("pose 2: marker and probe not seen (missing or out of volume) in 3 of the "
                "last 3 poses, above run.stop_skip_share 0.5") in err[0]
        assert f"resume with: tmscal acquire {pointed} -o {out} --resume" in err[0]
        assert sum("warn_skip_share" in ln for ln in r.stderr.splitlines()) == 1
    cfg = _rig(mock_config, missing=0.0)  # the line of sight cleared; the arm still at P0
    with start_mock_rig(load_config(cfg), tracker_transport="tcp") as mr:
        pointed = point_config(cfg, mr.endpoints)
        r = subprocess.run(_cli("acquire", str(pointed), "-o", str(out), "--resume"),
                           capture_output=True, text=True, timeout=240, env=_env(), cwd=REPO)
    assert r.returncode == 0, r.stderr[-2000:]
    assert sorted(p.index for p in read_session(out).poses) == list(range(10))


@pytest.mark.e2e
def test_tty_progress_fits_80_columns_and_shows_phase_eta_spread_skips(tmp_path, mock_config):
    cfg = _rig(mock_config, missing=0.2,
               run={"warn_skip_share": 1.0, "stop_skip_share": 1.0})
    out = tmp_path / "s.jsonl"
    with start_mock_rig(load_config(cfg), tracker_transport="tcp") as mr:
        pointed = point_config(cfg, mr.endpoints)
        code, text = _run_in_pty(_cli("acquire", str(pointed), "-o", str(out),
                                      "--poses", "15"))
    assert code == 0, text[-2000:]
    progress = text[:text.index("session ")]  # the summary follows the display
    screen = _screen_lines(progress)
    # the display's lines fit 80 columns; a skipped pose's whole reason is written above it
    reasons = [s for s in screen if re.match(r"pose \d+/15 skipped: ", s)]
    assert reasons and all("below min_share 0.8" in s for s in reasons), reasons
    assert max(len(s) for s in screen if s not in reasons) <= 80, [s for s in screen
                                                                   if len(s) > 80]
    assert "\r" in progress  # refreshed in place
    for phase in ("moving", "settling", "sampling"):
        assert any(s.startswith("pose ") and s.endswith(phase) for s in screen), phase
    assert any(s.startswith("pose 15/15 ") for s in screen)
    assert any(re.search(r"ETA \d\d:\d\d", s) for s in screen)
    assert any(re.match(r"marker spread \d\.\d{3} mm / \d\.\d{3}°  probe spread", s)
               for s in screen)
    n_skipped = sum(p.skipped is not None for p in read_session(out).poses)
    assert n_skipped > 0, "the fault should have made this run skip poses"
    last_status = [s for s in screen if s.startswith("skipped ")][-1]
    assert last_status.startswith(f"skipped {n_skipped}; last: ")
    assert "seen in" in last_status


@pytest.mark.e2e
def test_track_table_plain_and_in_place(tmp_path, mock_config):
    cfg = _rig(mock_config)
    with start_mock_rig(load_config(cfg), tracker_transport="tcp") as mr:
        pointed = point_config(cfg, mr.endpoints)
        r = subprocess.run(_cli("track", str(pointed), "--frames", "5"), capture_output=True,
                           text=True, timeout=120, env=_env(), cwd=REPO)
        code, text = _run_in_pty(_cli("track", str(pointed), "--frames", "400"))
        truth = {b: mr.rig.true_body(b) for b in ("marker", "probe")}
    assert r.returncode == 0, r.stderr
    assert "\r" not in r.stdout and "\x1b" not in r.stdout
    assert "rotation vector" in r.stdout and "rms mm" in r.stdout
    frames = [ln for ln in r.stdout.splitlines() if ln.startswith("frame ")]
    assert len(frames) == 5 and "Hz" in frames[-1]
    rows = [ln.split() for ln in r.stdout.splitlines() if ln.startswith("  marker ")
            or ln.startswith("  probe ")]
    assert len(rows) == 10 and all(row[1] == "yes" for row in rows)
    for row in rows[-2:]:  # position within the mock's noise of the true pose
        t = truth[row[0]][:3, 3]
        assert all(abs(float(v) - w) < 1.0 for v, w in zip(row[2:5], t)), (row, t)
    assert code == 0, text[-2000:]
    assert "\x1b[3A" in text  # redrawn in place: the cursor goes back up over the table
    screen = _screen_lines(text[text.index("position:"):])
    assert max(len(s) for s in screen) <= 80, [s for s in screen if len(s) > 80]


@pytest.mark.e2e
def test_track_ctrl_c_closes_the_tracker_quietly(tmp_path, mock_config):
    import signal

    cfg = _rig(mock_config)
    with start_mock_rig(load_config(cfg), tracker_transport="tcp") as mr:
        pointed = point_config(cfg, mr.endpoints)
        for _attempt in range(3):  # each run must find the tracker as the last one left it
            p = subprocess.Popen(_cli("track", str(pointed), "--plain"), stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True, env=_env(), cwd=REPO)
            seen = 0
            for line in p.stdout:  # frames stream in; the hang guard is the test timeout
                seen += line.startswith("frame ")
                if seen == 50:
                    break
            p.send_signal(signal.SIGINT)
            _, err = p.communicate(timeout=60)
            assert p.returncode == 0, err
            assert err == "", err  # no warning, no raw reply bytes, no error line


@pytest.mark.e2e
def test_output_into_a_closed_pipe_ends_quietly_with_141(tmp_path, mock_config):
    """`tmscal track CONFIG --plain | head -1` with a real pipe: track prints until it is
    stopped, so its writes after head has gone meet a closed pipe, whatever the timing. It
    ends at once with 141 (128 + SIGPIPE, as a shell reports a program its pipe ended) and
    writes nothing on stderr (before: "error: Broken pipe", exit 1)."""
    cfg = _rig(mock_config)
    with start_mock_rig(load_config(cfg), tracker_transport="tcp") as mr:
        pointed = point_config(cfg, mr.endpoints)
        track = subprocess.Popen(_cli("track", str(pointed), "--plain"),
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env(),
                                 cwd=REPO)
        head = subprocess.Popen(["head", "-1"], stdin=track.stdout, stdout=subprocess.PIPE)
        assert track.stdout is not None
        track.stdout.close()  # head holds the only read end
        first, _ = head.communicate(timeout=120)
        code = track.wait(timeout=120)
        err = track.stderr.read() if track.stderr else b""
    assert first.startswith(b"tracker: driver ndi"), first
    assert code == 141, err
    assert err == b"", err
