"""Small steps of the acquisition loop that need no device: an invalid measurement becomes a
skipped pose (never a line the reader rejects), and the resume command (``tmscal acquire`` or
``tmscal selfcal acquire``) repeats the device overrides only."""

from __future__ import annotations

import numpy as np

from tmscal.acquisition.engine import valid_or_skipped
from tmscal.acquisition.resume import resume_command
from tmscal.session import PoseRecord, SessionWriter, make_header, read_session


def test_nan_robot_pose_is_recorded_as_skipped_and_the_session_stays_readable(tmp_path):
    A = np.eye(4)
    A[0, 3] = np.nan
    rec = PoseRecord(index=0, A=A, B=np.eye(4), C=np.eye(4), commanded=np.eye(4),
                     samples={"A": 10, "B": 10, "C": 10}, spread={})
    out = valid_or_skipped(rec)
    assert out.skipped and "invalid measurement" in out.skipped and "'A'" in out.skipped
    assert out.A is None and out.B is None and out.index == 0
    good = PoseRecord(index=1, A=np.eye(4), B=np.eye(4), C=np.eye(4), commanded=np.eye(4))
    assert valid_or_skipped(good).skipped is None
    p = tmp_path / "s.jsonl"
    with SessionWriter.create(p, make_header(["marker", "probe"])) as w:
        w.append(out)
        w.append(valid_or_skipped(good))
    s = read_session(p, strict=True)
    assert [r.skipped is None for r in s.poses] == [False, True]


def test_resume_command_repeats_device_overrides_only():
    cmd = resume_command("rig.yaml", "s.jsonl", "/dev/pts/3", "127.0.0.5")
    assert cmd == ("tmscal acquire rig.yaml -o s.jsonl --resume --tracker-port /dev/pts/3 "
                   "--robot-host 127.0.0.5")
    assert "--samples" not in resume_command("rig.yaml", "s.jsonl")


def test_the_self_calibration_run_resumes_through_its_own_command():
    cmd = resume_command("rig.yaml", "s.jsonl", robot_host="127.0.0.5",
                         ft_host="127.0.0.6:49152", command="selfcal acquire")
    assert cmd == ("tmscal selfcal acquire rig.yaml -o s.jsonl --resume --robot-host "
                   "127.0.0.5 --ft-host 127.0.0.6:49152")
