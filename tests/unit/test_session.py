import json
import re

import numpy as np
import pytest

from tmscal.errors import SessionError
from tmscal.session import (
    PoseRecord,
    SessionWriter,
    make_header,
    read_session,
    records_from_arrays,
    write_session,
)

from ..rigs import simulated


def _sim(n=5, probe=True):
    return simulated(n, with_probe=probe)


def test_round_trip(tmp_path):
    truth, d = _sim()
    h = make_header(["marker", "probe"], truth={"X": truth.X, "Y": truth.Y, "Z": truth.Z})
    p = write_session(tmp_path / "s.jsonl", h, records_from_arrays(d["A"], d["marker"],
                                                                    d["probe"], d["commanded"]))
    s = read_session(p)
    A, B, C, idx = s.arrays(need_probe=True)
    np.testing.assert_array_equal(A, d["A"])
    np.testing.assert_array_equal(B, d["marker"])
    np.testing.assert_array_equal(C, d["probe"])
    assert idx == [0, 1, 2, 3, 4]
    np.testing.assert_array_equal(s.truth["Y"], truth.Y)
    lines = p.read_text().splitlines()
    assert json.loads(lines[0])["format"] == "tmscal-session"
    assert json.loads(lines[1])["kind"] == "pose" and len(lines) == 6


def test_marker_only_session(tmp_path):
    _, d = _sim(probe=False)
    p = write_session(tmp_path / "m.jsonl", make_header(["marker"]),
                      records_from_arrays(d["A"], d["marker"]))
    s = read_session(p)
    A, B, C, _ = s.arrays()
    assert C is None and len(B) == 5


def test_torn_last_line_is_ignored_and_resume_cuts_it(tmp_path, caplog):
    _, d = _sim()
    p = write_session(tmp_path / "s.jsonl", make_header(["marker", "probe"]),
                      records_from_arrays(d["A"][:3], d["marker"][:3], d["probe"][:3]))
    full = p.read_bytes()
    torn_line = json.dumps(records_from_arrays(d["A"], d["marker"], d["probe"])[3].to_json())
    p.write_bytes(full + torn_line[: len(torn_line) // 2].encode())
    s = read_session(p)
    assert s.torn_tail and len(s.poses) == 3 and s.good_bytes == len(full)
    assert "torn last line" in caplog.text
    with SessionWriter.resume(p) as w:
        w.append(records_from_arrays(d["A"], d["marker"], d["probe"])[3])
    s2 = read_session(p)
    assert not s2.torn_tail and [r.index for r in s2.poses] == [0, 1, 2, 3]


@pytest.mark.parametrize("mutate, match", [
    (lambda L: L.__setitem__(2, "{not json"), r"line 3: not valid JSON"),
    (lambda L: L.__setitem__(0, '{"kind": "header", "format": "other"}'), r"line 1: not a tmscal"),
    (lambda L: L.__setitem__(1, L[1].replace('"index":0', '"index":"zero"')),
     r"line 2: field 'index'"),
    (lambda L: L.__setitem__(2, L[2].replace('"index":1', '"index":0')),
     r"line 3: pose index 0 already on line 2"),
    (lambda L: L.__setitem__(1, L[1].replace('"A":[[', '"A":[[7,')), r"line 2: field 'A'"),
])
def test_malformed_lines_name_line_and_field(tmp_path, mutate, match):
    _, d = _sim()
    p = write_session(tmp_path / "s.jsonl", make_header(["marker", "probe"]),
                      records_from_arrays(d["A"], d["marker"], d["probe"]))
    lines = p.read_text().splitlines()
    mutate(lines)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(SessionError, match=match):
        read_session(p, strict=True)
    # by default a damaged pose line is skipped, named, and the other poses are kept
    no = int(re.search(r"line (\d+)", match).group(1))
    if no == 1:  # a damaged header is always an error
        with pytest.raises(SessionError, match=match):
            read_session(p)
        return
    s = read_session(p)
    assert [d[0] for d in s.damaged] == [no]
    assert len(s.poses) == 4 and s.torn_tail is False
    assert s.damage_summary().startswith(f"1 damaged line skipped: line {no} (")


def test_damaged_header_is_always_an_error(tmp_path):
    _, d = _sim()
    p = write_session(tmp_path / "s.jsonl", make_header(["marker", "probe"]),
                      records_from_arrays(d["A"], d["marker"], d["probe"]))
    lines = p.read_text().splitlines()
    lines[0] = lines[0][:-3]
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(SessionError, match=r"line 1: not valid JSON"):
        read_session(p)


def test_unreadable_and_empty(tmp_path):
    with pytest.raises(SessionError, match="cannot read"):
        read_session(tmp_path / "missing.jsonl")
    (tmp_path / "e.jsonl").write_text("")
    with pytest.raises(SessionError, match="empty"):
        read_session(tmp_path / "e.jsonl")


def test_writer_refuses_overwrite_and_duplicate(tmp_path):
    p = tmp_path / "s.jsonl"
    p.write_text("precious\n")
    with pytest.raises(SessionError, match="refusing to overwrite"):
        SessionWriter.create(p, make_header(["marker"]))
    assert p.read_text() == "precious\n"
    q = tmp_path / "q.jsonl"
    with SessionWriter.create(q, make_header(["marker"])) as w:
        w.append(PoseRecord(index=0, A=np.eye(4), B=np.eye(4)))
        with pytest.raises(SessionError, match="already recorded"):
            w.append(PoseRecord(index=0, A=np.eye(4), B=np.eye(4)))


def test_skipped_pose_is_kept_but_not_used(tmp_path):
    q = tmp_path / "q.jsonl"
    with SessionWriter.create(q, make_header(["marker"])) as w:
        w.append(PoseRecord(index=0, A=np.eye(4), B=np.eye(4)))
        w.append(PoseRecord(index=1, A=np.eye(4), B=None, skipped="marker missing in 90%"))
    s = read_session(q)
    assert s.poses[1].skipped == "marker missing in 90%"
    assert s.arrays()[3] == [0]
