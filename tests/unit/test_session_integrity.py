"""Session data integrity (issue 8): the writer refuses what the reader would reject, damaged
lines are salvaged rather than locking the session, writers lock the file, only regular files
are read, and every kind of bad input is a SessionError naming the file and the line."""

from __future__ import annotations

import errno
import fcntl
import json
import multiprocessing
import os
import re
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from tmscal.errors import SessionError
from tmscal.session import (
    PoseRecord,
    Session,
    SessionWriter,
    make_header,
    read_session,
    records_from_arrays,
    validate_record,
    write_session,
)
from tmscal.session import files as session_mod

from ..rigs import simulated

_TRUTH, _D = simulated(6)
_RECS = records_from_arrays(_D["A"], _D["marker"], _D["probe"], _D["commanded"], samples=10)
_HEADER = make_header(["marker", "probe"])


def _session(tmp_path: Path, n: int = 6, name: str = "s.jsonl") -> Path:
    return write_session(tmp_path / name, _HEADER, _RECS[:n])


def _rec(i: int = 0, **kw) -> PoseRecord:
    r = records_from_arrays(_D["A"], _D["marker"], _D["probe"], _D["commanded"])[i]
    for k, v in kw.items():
        setattr(r, k, v)
    return r


def _with_nan(M: np.ndarray) -> np.ndarray:
    M = np.array(M)
    M[1, 3] = np.nan
    return M


# --- item 8a: validate before writing -------------------------------------------------------

@pytest.mark.parametrize("change, field", [
    ({"A": _with_nan(_D["A"][0])}, "'A': contains NaN"),
    ({"B": np.full((4, 4), np.inf)}, "'B'"),
    ({"C": np.eye(4) * 2}, "'C': last row"),
    ({"commanded": np.eye(3)}, "'commanded': expected a 4×4"),
    ({"A": np.diag([1.0, 2.0, 1.0, 1.0])}, "'A': not a rigid transform"),
    ({"A": np.array([[1e308, 0, 0, 0], [0, 1e308, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])},
     "'A': not a rigid"),
    ({"index": -1}, "'index'"),
    ({"time": float("nan")}, "'time'"),
    ({"time": float("inf")}, "'time'"),
    ({"samples": {"A": object()}}, "'samples'"),
    ({"samples": {"A": -3}}, "'samples'"),
    ({"samples": {"A": float("nan")}}, "'samples'"),
    ({"spread": {"marker": {"trans_mm": float("nan"), "rot_deg": 0.0}}}, "'spread'"),
    ({"spread": {"marker": [1, 2]}}, "'spread'"),
    ({"spread": {"marker": {"trans_mm": {1, 2}}}}, "'spread'"),
    ({"skipped": 5}, "'skipped'"),
    ({"skipped": "bad \udc80 text"}, "'skipped'"),
    ({"A": None}, "'A' is missing"),
])
def test_append_refuses_what_the_reader_rejects_and_writes_nothing(tmp_path, change, field):
    p = _session(tmp_path, 3)
    before = p.read_bytes()
    rec = _rec(3, **change)
    with SessionWriter.resume(p) as w:
        with pytest.raises(SessionError) as ei:
            w.append(rec)
        msg = str(ei.value)
        assert str(p) in msg and f"pose {rec.index}" in msg and field in msg, msg
        assert w.session.indices() == {0, 1, 2}
        w.append(_rec(3))  # the writer is still usable after a refusal
    after = p.read_bytes()
    assert after.startswith(before) and after.count(b"\n") == before.count(b"\n") + 1
    s = read_session(p, strict=True)
    assert [r.index for r in s.poses] == [0, 1, 2, 3] and not s.damaged


def test_validate_record_returns_what_reads_back():
    rec = _rec(2, samples={"A": np.int64(10), "B": 9}, spread={"A": {"trans_mm": np.float64(0.5),
                                                                      "rot_deg": 0.0}})
    back = validate_record(rec)
    assert back.samples == {"A": 10, "B": 9} and type(back.samples["A"]) is int
    np.testing.assert_array_equal(back.A, rec.A)
    with pytest.raises(SessionError, match=r"^run\.jsonl: pose 2: field 'A'"):
        validate_record(_rec(2, A=_with_nan(rec.A)), "run.jsonl")


@pytest.mark.parametrize("kw, match", [
    ({"config": {"gain": float("nan")}}, "field 'config' is not storable as JSON"),
    ({"config": {"when": object()}}, "field 'config' is not storable as JSON"),
    ({"devices": {"robot": {"x": float("inf")}}}, "field 'devices' is not storable"),
    ({"truth": {"X": np.eye(4)}}, r"'truth\.Z' is missing"),
    ({"truth": {"X": np.eye(4), "Z": _with_nan(np.eye(4))}}, r"'truth\.Z': contains NaN"),
    ({"plan": [1, 2]}, "'plan' must be an object"),
])
def test_make_header_refuses_a_header_the_reader_rejects(kw, match):
    with pytest.raises(SessionError, match=match):
        make_header(["marker"], **kw)
    with pytest.raises(SessionError, match="'bodies'"):
        make_header([])


def test_create_refuses_a_bad_header_and_creates_nothing(tmp_path):
    p = tmp_path / "s.jsonl"
    h = dict(_HEADER, bodies=["marker", "marker"])
    with pytest.raises(SessionError, match=rf"{p}: header: field 'bodies'"):
        SessionWriter.create(p, h)
    h = dict(_HEADER, config={"x": float("nan")})
    with pytest.raises(SessionError, match="not storable as JSON"):
        SessionWriter.create(p, h)
    assert not p.exists()


# --- item 8b/c: damaged lines are skipped, reported and kept --------------------------------

def _inject(p: Path, line_no: int, text: bytes) -> None:
    lines = p.read_bytes().split(b"\n")
    lines.insert(line_no - 1, text)
    p.write_bytes(b"\n".join(lines))


def _nan_line(i: int) -> bytes:
    """A pose line as an old writer would have written a NaN CurPos."""
    d = _rec(i).to_json()
    d["A"][0][3] = float("nan")
    return json.dumps(d).encode()


def test_a_nan_line_in_the_middle_is_skipped_not_fatal(tmp_path, caplog):
    p = _session(tmp_path, 6)
    lines = p.read_bytes().split(b"\n")
    lines[3] = _nan_line(2)  # pose 2 is damaged
    p.write_bytes(b"\n".join(lines))
    s = read_session(p)
    assert [r.index for r in s.poses] == [0, 1, 3, 4, 5]
    assert s.damaged == [(4, "not valid JSON (non-finite number NaN (JSON has no NaN or "
                             "infinity))")]
    assert f"{p}, line 4: damaged line skipped" in caplog.text
    assert s.damage_summary() == f"1 damaged line skipped: line 4 ({s.damaged[0][1]})"
    assert not s.torn_tail and s.good_bytes == p.stat().st_size
    with pytest.raises(SessionError, match=rf"{p}, line 4: not valid JSON"):
        read_session(p, strict=True)


def test_damage_summary_lists_a_few_and_counts_the_rest(tmp_path):
    s = Session(header={}, poses=[], damaged=[(i, "x") for i in range(2, 10)])
    assert s.damage_summary(limit=2) == ("8 damaged lines skipped: line 2 (x), line 3 (x), "
                                         "and 6 more")
    assert Session(header={}, poses=[]).damage_summary() is None


def test_duplicate_index_keeps_the_first(tmp_path):
    p = _session(tmp_path, 3)
    other = _rec(4)
    other.index = 1
    with open(p, "ab") as fh:
        fh.write(json.dumps(other.to_json()).encode() + b"\n")
    s = read_session(p)
    assert [r.index for r in s.poses] == [0, 1, 2]
    np.testing.assert_array_equal(s.poses[1].A, _D["A"][1])
    assert s.damaged == [(5, "pose index 1 already on line 3")]


def test_resume_keeps_damaged_lines_and_the_reacquired_pose_is_no_duplicate(tmp_path):
    p = _session(tmp_path, 5)
    lines = p.read_bytes().split(b"\n")
    lines[3] = _nan_line(2)
    lines[4] = b'{"kind":"pose","index":3,"A":"garbage"}'
    p.write_bytes(b"\n".join(lines))
    before = p.read_bytes()
    with SessionWriter.resume(p) as w:
        assert w.session.indices() == {0, 1, 4}  # 2 and 3 count as not recorded
        w.append(_rec(2))
        w.append(_rec(3))
        with pytest.raises(SessionError, match="already recorded"):
            w.append(_rec(4))
    after = p.read_bytes()
    assert after.startswith(before)  # nothing rewritten, only appended
    s = read_session(p)
    assert sorted(r.index for r in s.poses) == [0, 1, 2, 3, 4]
    assert [no for no, _ in s.damaged] == [4, 5]
    np.testing.assert_array_equal(s.poses[-2].A, _D["A"][2])


def test_resume_cuts_only_a_torn_tail_after_damage(tmp_path):
    p = _session(tmp_path, 4)
    _inject(p, 3, b"{broken")
    full = p.read_bytes()
    p.write_bytes(full + json.dumps(_rec(4).to_json()).encode()[:50])
    s = read_session(p)
    assert s.torn_tail and s.good_bytes == len(full) and [n for n, _ in s.damaged] == [3]
    with SessionWriter.resume(p) as w:
        w.append(_rec(4))
    assert p.read_bytes() == full + json.dumps(_rec(4).to_json(),
                                               separators=(",", ":")).encode() + b"\n"


def test_power_cut_tail_of_nul_bytes_is_torn(tmp_path):
    p = _session(tmp_path, 3)
    full = p.read_bytes()
    p.write_bytes(full + b"\0" * 300)
    s = read_session(p)
    assert s.torn_tail and len(s.poses) == 3 and not s.damaged
    with SessionWriter.resume(p) as w:
        w.append(_rec(3))
    assert read_session(p, strict=True).indices() == {0, 1, 2, 3}


def test_a_complete_last_line_without_newline_is_kept_and_terminated(tmp_path):
    p = _session(tmp_path, 3)
    p.write_bytes(p.read_bytes()[:-1])
    s = read_session(p, strict=True)
    assert s.indices() == {0, 1, 2} and not s.torn_tail
    with SessionWriter.resume(p) as w:
        w.append(_rec(3))
    assert read_session(p, strict=True).indices() == {0, 1, 2, 3}


def test_bom_and_crlf_are_accepted(tmp_path):
    p = _session(tmp_path, 3)
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes().replace(b"\n", b"\r\n"))
    s = read_session(p, strict=True)
    assert s.indices() == {0, 1, 2} and s.good_bytes == p.stat().st_size
    with SessionWriter.resume(p) as w:
        w.append(_rec(3))
    assert read_session(p, strict=True).indices() == {0, 1, 2, 3}


# --- item 12: every bad input is a SessionError naming file and line -----------------------

_BAD_VALUES = {
    "deep nesting": b"[" * 100_000,
    "deep object": b'{"a":' * 50_000,
    "huge integer literal": b"1" * 5000,
    "10**400": b'{"kind":"pose","index":0,"A":[[1' + b"0" * 400 + b',0,0,0],[0,1,0,0],'
               b'[0,0,1,0],[0,0,0,1]]}',
    "1e400": b'{"kind":"pose","index":0,"time":1e400,"A":null,"skipped":"x"}',
    "NaN literal": b'{"kind":"pose","index":0,"time":NaN,"A":null,"skipped":"x"}',
    "-Infinity": b'{"kind":"pose","index":0,"time":-Infinity,"A":null,"skipped":"x"}',
    "1e308 translation": b'{"kind":"pose","index":0,"A":[[1,0,0,1e308],[0,1,0,1e308],'
                         b'[0,0,1,1e308],[0,0,0,1]]}',
    "1e308 rotation": b'{"kind":"pose","index":0,"A":[[1e308,1e308,0,0],[1e308,1e308,0,0],'
                      b'[0,0,1,0],[0,0,0,1]]}',
    "string entries": b'{"kind":"pose","index":0,"A":[["1","0","0","0"],["0","1","0","0"],'
                      b'["0","0","1","0"],["0","0","0","1"]]}',
    "bool entries": b'{"kind":"pose","index":0,"A":[[true,0,0,0],[0,true,0,0],'
                    b'[0,0,true,0],[0,0,0,true]]}',
    "reflection": b'{"kind":"pose","index":0,"A":[[1,0,0,0],[0,1,0,0],[0,0,-1,0],[0,0,0,1]]}',
    "ragged matrix": b'{"kind":"pose","index":0,"A":[[1,0,0,0],[0,1,0],[0,0,1,0],[0,0,0,1]]}',
    "huge index": b'{"kind":"pose","index":100000000000000000000,"A":null,"skipped":"x"}',
    "bool index": b'{"kind":"pose","index":true,"A":null,"skipped":"x"}',
    "samples list": b'{"kind":"pose","index":0,"A":null,"skipped":"x","samples":[1]}',
    "samples string": b'{"kind":"pose","index":0,"A":null,"skipped":"x","samples":{"A":"9"}}',
    "spread numbers": b'{"kind":"pose","index":0,"A":null,"skipped":"x","spread":{"A":1}}',
    "spread nested": b'{"kind":"pose","index":0,"A":null,"skipped":"x",'
                     b'"spread":{"A":{"t":[1]}}}',
    "time string": b'{"kind":"pose","index":0,"time":"now","A":null,"skipped":"x"}',
    "time huge int": b'{"kind":"pose","index":0,"time":1' + b"0" * 400
                     + b',"A":null,"skipped":"x"}',
    "skipped object": b'{"kind":"pose","index":0,"A":null,"skipped":{"a":1}}',
    "lone surrogate": b'{"kind":"pose","index":0,"A":null,"skipped":"\\udc80"}',
    "invalid utf-8": b'{"kind":"pose","index":0,"A":null,"skipped":"\xff\xfe"}',
    "NUL byte": b'{"kind":"pose","index":0,"A":null,\0"skipped":"x"}',
    "BOM mid-file": b'\xef\xbb\xbf{"kind":"pose","index":0,"A":null,"skipped":"x"}',
    "empty line": b"",
    "whitespace": b"   \t\r",
    "array": b"[1,2,3]",
    "number": b"42",
    "null": b"null",
    "header again": json.dumps(_HEADER).encode(),
}


@pytest.mark.parametrize("bad", list(_BAD_VALUES.values()), ids=list(_BAD_VALUES))
def test_bad_pose_lines_are_damaged_lines(tmp_path, bad):
    p = _session(tmp_path, 3)
    _inject(p, 3, bad)
    s = read_session(p)
    assert [r.index for r in s.poses] == [0, 1, 2] and [n for n, _ in s.damaged] == [3]
    with pytest.raises(SessionError, match=rf"^{p}, line 3: "):
        read_session(p, strict=True)


_BAD_HEADERS = {
    "truth without Z": dict(_HEADER, truth={"X": np.eye(4).tolist()}),
    "truth weird key": dict(_HEADER, truth={"X": np.eye(4).tolist(), "Z": np.eye(4).tolist(),
                                            "W": 1}),
    "truth list": dict(_HEADER, truth=[1, 2]),
    "truth NaN-free but not rigid": dict(_HEADER, truth={"X": np.eye(4).tolist(),
                                                         "Z": (2 * np.eye(4)).tolist()}),
    "bodies numbers": dict(_HEADER, bodies=[1, 2]),
    "bodies empty string": dict(_HEADER, bodies=[""]),
    "bodies string": dict(_HEADER, bodies="marker"),
    "version true": dict(_HEADER, version=True),
    "version 2": dict(_HEADER, version=2),
    "units cm": dict(_HEADER, units={"length": "cm"}),
    "config list": dict(_HEADER, config=[1]),
    "created number": dict(_HEADER, created=5),
}


@pytest.mark.parametrize("header", list(_BAD_HEADERS.values()), ids=list(_BAD_HEADERS))
def test_bad_headers_are_errors_naming_line_1(tmp_path, header):
    p = tmp_path / "h.jsonl"
    p.write_text(json.dumps(header) + "\n" + json.dumps(_rec(0).to_json()) + "\n")
    for strict in (False, True):
        with pytest.raises(SessionError, match=rf"^{p}, line 1: "):
            read_session(p, strict=strict)


_NOT_HEADERS = [k for k in _BAD_VALUES if k not in ("empty line", "header again")]


@pytest.mark.parametrize("bad", [_BAD_VALUES[k] for k in _NOT_HEADERS], ids=_NOT_HEADERS)
def test_bad_header_lines_are_errors(tmp_path, bad):
    p = tmp_path / "h.jsonl"
    p.write_bytes(bad + b"\n" + json.dumps(_rec(0).to_json()).encode() + b"\n")
    with pytest.raises(SessionError, match=rf"^{p}(, line 1)?: "):
        read_session(p)


def test_overflowing_number_in_the_header_is_an_error(tmp_path):
    p = tmp_path / "h.jsonl"
    text = json.dumps(dict(_HEADER, config={"gain": "X"})).replace('"X"', "1e400")
    p.write_text(text + "\n" + json.dumps(_rec(0).to_json()) + "\n")
    with pytest.raises(SessionError, match=rf"^{p}, line 1: not valid JSON \(number 1e400"):
        read_session(p)


def test_truth_property_never_crashes_later(tmp_path):
    h = make_header(["marker", "probe"], truth={"X": _TRUTH.X, "Y": None, "Z": _TRUTH.Z})
    p = write_session(tmp_path / "t.jsonl", h, _RECS[:2])
    s = read_session(p)
    assert set(s.truth) == {"X", "Z"}
    s.header["truth"] = {"X": _TRUTH.X.tolist(), "Y": _TRUTH.Y.tolist()}  # mutated by a caller
    with pytest.raises(SessionError, match=r"'truth\.Z' is missing"):
        _ = s.truth


# --- only regular files; never hang ---------------------------------------------------------

def _no_hang(fn, fifo: Path | None = None) -> BaseException | None:
    """Run fn in a thread; if it blocks on the FIFO, unblock it by opening the other end (so
    a regression fails the test instead of hanging the suite)."""
    out: list[BaseException | None] = [None]

    def run() -> None:
        try:
            fn()
        except BaseException as e:  # noqa: BLE001 - handed back to the test
            out[0] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(30)
    if t.is_alive() and fifo is not None:
        fd = os.open(fifo, os.O_RDWR | os.O_NONBLOCK)
        os.close(fd)
        t.join(5)
        pytest.fail("blocked on a FIFO")
    return out[0]


@pytest.mark.parametrize("action", ["read", "resume", "create", "overwrite"])
def test_fifo_is_refused_without_blocking(tmp_path, action):
    f = tmp_path / "fifo.jsonl"
    os.mkfifo(f)
    fn = {"read": lambda: read_session(f), "resume": lambda: SessionWriter.resume(f),
          "create": lambda: SessionWriter.create(f, _HEADER),
          "overwrite": lambda: SessionWriter.create(f, _HEADER, overwrite=True)}[action]
    e = _no_hang(fn, f)
    assert isinstance(e, SessionError), e
    assert str(f) in str(e)
    if action != "create":
        assert "not a regular file" in str(e)


def test_directory_is_refused(tmp_path):
    for fn in (lambda: read_session(tmp_path), lambda: SessionWriter.resume(tmp_path),
               lambda: SessionWriter.create(tmp_path, _HEADER, overwrite=True)):
        with pytest.raises(SessionError, match=rf"^{tmp_path}: "):
            fn()


# --- item 9: the lock and O_APPEND ---------------------------------------------------------

_LOCKED = "in use by another tmscal process (locked)"


def test_two_writers_in_one_process_conflict(tmp_path):
    p = tmp_path / "s.jsonl"
    w = SessionWriter.create(p, _HEADER)
    w.append(_rec(0))
    before = p.read_bytes()
    with pytest.raises(SessionError, match=rf"^{p}: {re.escape(_LOCKED)}"):
        SessionWriter.resume(p)
    with pytest.raises(SessionError, match="locked"):
        SessionWriter.create(p, _HEADER, overwrite=True)
    assert p.read_bytes() == before  # the overwrite did not truncate a locked session
    w.close()
    w.close()  # safe twice
    with SessionWriter.resume(p) as w2:  # free again once closed
        with pytest.raises(SessionError, match="locked"):
            SessionWriter.resume(p)
        w2.append(_rec(1))
    assert read_session(p, strict=True).indices() == {0, 1}


def test_the_writer_holds_the_flock_and_appends(tmp_path):
    p = tmp_path / "s.jsonl"
    with SessionWriter.create(p, _HEADER) as w:
        assert fcntl.fcntl(w._fd, fcntl.F_GETFL) & os.O_APPEND
        fd = os.open(p, os.O_RDONLY)
        try:
            with pytest.raises(BlockingIOError):
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(fd)
        # bytes added behind the writer's back are never overwritten (O_APPEND)
        with open(p, "ab") as fh:
            fh.write(json.dumps(_rec(5).to_json()).encode() + b"\n")
        w.append(_rec(0))
    s = read_session(p, strict=True)
    assert [r.index for r in s.poses] == [5, 0]


def test_failed_write_leaves_no_partial_line(tmp_path, monkeypatch):
    p = _session(tmp_path, 2)
    before = p.read_bytes()
    real_write = os.write

    def half_then_enospc(fd, data):
        real_write(fd, bytes(data[: len(data) // 2]))
        raise OSError(errno.ENOSPC, "No space left on device")

    with SessionWriter.resume(p) as w:
        monkeypatch.setattr(session_mod.os, "write", half_then_enospc)
        with pytest.raises(SessionError, match=r"cannot append pose 2 \(No space left"):
            w.append(_rec(2))
        monkeypatch.setattr(session_mod.os, "write", real_write)
        assert p.read_bytes() == before
        w.append(_rec(2))
    assert read_session(p, strict=True).indices() == {0, 1, 2}


_HOLDER = """
import sys
from tmscal.session import SessionWriter
w = SessionWriter.resume(sys.argv[1])
print("locked", flush=True)
sys.stdin.read()
w.close()
"""


def test_a_writer_in_another_process_blocks_resume_and_create(tmp_path):
    p = _session(tmp_path, 2)
    before = p.read_bytes()
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(p)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, cwd=Path(__file__).resolve().parents[2])
    try:
        assert proc.stdout.readline().strip() == b"locked"
        with pytest.raises(SessionError, match=re.escape(_LOCKED)):
            SessionWriter.resume(p)
        with pytest.raises(SessionError, match="locked"):
            SessionWriter.create(p, _HEADER, overwrite=True)
        assert p.read_bytes() == before
    finally:
        proc.stdin.close()
        assert proc.wait(60) == 0
    with SessionWriter.resume(p) as w:  # released when the other process closed it
        w.append(_rec(2))


def _race_create(path: str, barrier, q) -> None:
    from tmscal.session import SessionWriter, make_header
    barrier.wait()
    try:
        w = SessionWriter.create(path, make_header(["marker"], config={"pid": os.getpid()}))
    except SessionError as e:
        q.put(("refused", str(e)))
        return
    q.put(("created", os.getpid()))
    barrier.wait()  # hold the file until every process has tried
    w.close()


def test_racing_creators_exactly_one_wins(tmp_path):
    n = 4
    ctx = multiprocessing.get_context("spawn")
    barrier = ctx.Barrier(n)
    q = ctx.Queue()
    path = str(tmp_path / "race.jsonl")
    ps = [ctx.Process(target=_race_create, args=(path, barrier, q)) for _ in range(n)]
    for pr in ps:
        pr.start()
    results = [q.get(timeout=120) for _ in range(n)]
    barrier.abort()  # the losers never reach the second wait; release the winner
    for pr in ps:
        pr.join(60)
    created = [r for r in results if r[0] == "created"]
    assert len(created) == 1, results
    assert all("already exists" in r[1] for r in results if r[0] == "refused")
    h = read_session(path).header
    assert h["config"]["pid"] == created[0][1]  # the file is the winner's, written once
    assert Path(path).read_bytes().count(b"\n") == 1


# --- item 18a: one fsync per appended line, after the line is written ------------------------

def test_every_appended_line_is_fsynced_after_it_is_written(tmp_path, monkeypatch):
    p = tmp_path / "s.jsonl"
    calls: list[tuple[int, bytes]] = []
    real_fsync = os.fsync

    def spy(fd: int) -> None:
        calls.append((fd, p.read_bytes()))  # what is in the file when fsync is asked
        real_fsync(fd)

    with SessionWriter.create(p, _HEADER) as w:
        monkeypatch.setattr(session_mod.os, "fsync", spy)
        for i in range(4):
            n_before = len(calls)
            w.append(_rec(i))
            line = json.dumps(_rec(i).to_json(), separators=(",", ":")).encode() + b"\n"
            new = calls[n_before:]
            assert len(new) == 1, f"pose {i}: {len(new)} fsync calls"
            fd, content = new[0]
            assert fd == w._fd
            assert content.endswith(line), f"pose {i}: fsync before the line was written"
        monkeypatch.setattr(session_mod.os, "fsync", real_fsync)
    assert len(calls) == 4
