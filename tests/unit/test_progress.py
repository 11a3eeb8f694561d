"""The pieces of the run display that need no device: device stderr captured into the log
(a child process writing to file descriptor 2), the 80-column rule, the plain per-pose
lines, and the skip watch that warns and stops."""

from __future__ import annotations

import io
import logging
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tmscal.acquisition.skips import SkipWatch
from tmscal.cli.progress import AcquireProgress, fit, stderr_to_log
from tmscal.config import RunConfig, parse_config
from tmscal.errors import ConfigError
from tmscal.session import PoseRecord, seen_text, skip_cause


def test_child_and_c_level_stderr_go_to_the_log_and_fd2_is_restored(caplog, capfd):
    logger = logging.getLogger("test.devices.stderr")
    with caplog.at_level(logging.WARNING, logger="test.devices.stderr"):
        with stderr_to_log(logger):
            subprocess.run([sys.executable, "-c",
                            "import os; os.write(2, b'rtde: first line\\nsecond line\\n')"],
                           check=True)
            os.write(2, b"from this process, fd 2\n")
            subprocess.run([sys.executable, "-c", "import os; os.write(2, b'no newline')"],
                           check=True)
            print("python's own stderr", file=sys.stderr)
        os.write(2, b"after the capture\n")
    got = [r.getMessage() for r in caplog.records if r.name == "test.devices.stderr"]
    assert got == ["rtde: first line", "second line", "from this process, fd 2",
                   "no newline"]
    err = capfd.readouterr().err
    assert "python's own stderr" in err and "after the capture" in err
    assert "rtde: first line" not in err


def test_log_lines_written_during_the_capture_do_not_loop_through_it(capfd):
    root = logging.getLogger()
    h = logging.StreamHandler(sys.stderr)
    root.addHandler(h)
    try:
        with stderr_to_log(logging.getLogger("test.loop")):
            logging.getLogger("test.loop").warning("a warning of our own")
            os.write(2, b"a device line\n")
    finally:
        root.removeHandler(h)
    err = capfd.readouterr().err
    assert err.count("a warning of our own") == 1 and err.count("a device line") == 1


@given(st.lists(st.text(min_size=0, max_size=120), min_size=1, max_size=6),
       st.integers(20, 120), st.booleans())
def test_fit_never_exceeds_the_width_and_keeps_the_first_field(fields, width, cut):
    line = fit(fields, width, cut=cut)
    assert len(line) <= width
    assert line.startswith(fields[0][:width - 1])


def _rec(i: int, skipped: str | None = None, spread: float = 0.04) -> PoseRecord:
    sp = {} if skipped else {b: {"trans_mm": spread, "rot_deg": 2 * spread}
                             for b in ("marker", "probe")}
    return PoseRecord(index=i, A=None if skipped else np.eye(4),
                      B=None if skipped else np.eye(4), C=None if skipped else np.eye(4),
                      commanded=np.eye(4), spread=sp, skipped=skipped)


_HIDDEN = "probe seen in 0 of 100 frames, below min_share 0.8 (missing or out of the volume)"
#: intermittent dropouts: both tools seen, in fewer frames than min_share
_FLICKER = ("marker seen in 68 of 100 frames, probe seen in 72 of 100 frames, below min_share "
            "0.9 (dropouts, partly hidden or at the volume's edge)")


def test_plain_lines_count_skips_from_a_resumed_session_and_carry_the_whole_reason():
    """A measured pose's line fits 80 columns; a skipped pose's line carries its whole
    reason, the shares and min_share included, however long."""
    out = io.StringIO()
    p = AcquireProgress(out, tty=False)
    p.started(done=10, total=500, skipped=4)
    p.pose(11, 500, _rec(10, spread=0.045))
    p.pose(12, 500, _rec(11, skipped=_FLICKER))
    lines = out.getvalue().splitlines()
    assert len(lines) == 2 and "\r" not in out.getvalue()
    assert lines[0].startswith("pose 11/500  ETA ")
    assert "skipped 4  marker spread 0.045 mm / 0.090°" in lines[0]
    assert len(lines[0]) <= 80
    assert lines[1].endswith(f"skipped (5 so far): {_FLICKER}")
    assert len(lines[1]) > 80


def test_skip_cause_names_the_bodies_not_seen_or_seen_too_rarely():
    assert skip_cause(_HIDDEN) == "probe not seen (missing or out of volume)"
    assert skip_cause(_FLICKER) == ("marker and probe seen in too few frames (below "
                                    "min_share 0.9)")
    assert seen_text(_FLICKER) == "marker 68 of 100 frames, probe 72 of 100"
    # a session of an earlier version: "usable in", the share as a percentage
    old = "marker usable in 1 of 10 frames (< 80%: x); probe usable in 0 of 10 frames (< 80%)"
    assert skip_cause(old) == "marker and probe seen in too few frames (below min_share 0.8)"
    assert skip_cause("probe usable in 0 of 5 frames") == ("probe not seen (missing or out "
                                                          "of volume)")
    assert skip_cause("invalid measurement (pose 'A' is not finite)") == "invalid measurement"
    assert seen_text("invalid measurement (pose 'A' is not finite)") is None


def test_skip_watch_names_min_share_and_the_measured_shares_of_dropouts():
    """Tools seen in some frames but fewer than min_share are not "not seen": the warning
    names min_share and how often the last such pose saw each tool."""
    w = SkipWatch(RunConfig(warn_skip_share=0.1, stop_skip_share=0.5, skip_window=20))
    said = [w.add(_rec(i, skipped=_FLICKER)) for i in range(3)]
    assert said[2][0] == ("marker and probe seen in too few frames (below min_share 0.9) in 3 "
                          "of the last 3 poses (the last: marker 68 of 100 frames, probe 72 "
                          "of 100), above run.warn_skip_share 0.1; check the tools' line of "
                          "sight")


def test_skip_watch_warns_once_past_the_first_share_and_stops_past_the_second():
    w = SkipWatch(RunConfig(warn_skip_share=0.1, stop_skip_share=0.5, skip_window=20))
    said = [w.add(_rec(i, skipped=_HIDDEN if i % 2 else None)) for i in range(24)]
    warns = [i for i, (warn, _) in enumerate(said) if warn]
    stops = [i for i, (_, stop) in enumerate(said) if stop]
    assert warns == [5]  # the third skip of the window: 3 > 10 % of 20
    assert "probe not seen (missing or out of volume) in 3 of the last 6 poses" in said[5][0]
    assert stops == []  # every other pose: 10 of 20 is not above 50 %
    w2 = SkipWatch(RunConfig(warn_skip_share=0.1, stop_skip_share=0.5, skip_window=20))
    said = [w2.add(_rec(i, skipped=_HIDDEN if i % 4 else None)) for i in range(20)]
    stops = [i for i, (_, stop) in enumerate(said) if stop]
    assert stops and stops[0] == 14  # the eleventh skip: 11 of 15 poses
    assert said[14][1].startswith("probe not seen (missing or out of volume) in 11 of the "
                                  "last 15 poses")


def test_a_stop_for_skips_gives_the_windows_count_and_the_sessions_total():
    """The session already holds 3 skipped poses (a resumed run); in the window, 11 poses are
    skipped, 9 for the hidden probe and 2 for an invalid measurement: the message says the
    commonest cause's count, the window's 11 and the session's 14 (issue 24, item 6)."""
    w = SkipWatch(RunConfig(warn_skip_share=0.1, stop_skip_share=0.5, skip_window=20),
                  skipped_before=3)
    causes = [_HIDDEN] * 9 + ["invalid measurement (pose 'A' is not finite)"] * 2
    said = [w.add(_rec(i, skipped=c)) for i, c in enumerate(causes)]
    assert said[-1][1] == ("probe not seen (missing or out of volume) in 9 of the last 11 "
                           "poses (11 skipped in the window, 14 in the session), above "
                           "run.stop_skip_share 0.5")
    assert w.session_skipped == 14


def test_skip_watch_warns_again_after_the_share_fell_back():
    w = SkipWatch(RunConfig(warn_skip_share=0.0, stop_skip_share=1.0, skip_window=3))
    seq = [_HIDDEN, None, None, None, _HIDDEN]
    warns = [bool(w.add(_rec(i, skipped=s))[0]) for i, s in enumerate(seq)]
    assert warns == [True, False, False, False, True]


@pytest.mark.parametrize("run, key", [
    ({"warn_skip_share": 1.5}, "run.warn_skip_share"),
    ({"stop_skip_share": -0.1}, "run.stop_skip_share"),
    ({"warn_skip_share": 0.6, "stop_skip_share": 0.5}, "run.warn_skip_share"),
    ({"skip_window": 0}, "run.skip_window"),
    ({"stop_skip_share": "half"}, "run.stop_skip_share"),
])
def test_bad_skip_settings_are_refused_naming_the_key(run, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        parse_config({"run": run}, "rig.yaml")


def test_skip_settings_default_to_ten_and_fifty_percent_of_twenty_poses():
    r = parse_config({}, "rig.yaml").run
    assert (r.warn_skip_share, r.stop_skip_share, r.skip_window) == (0.10, 0.5, 20)
