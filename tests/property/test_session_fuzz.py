"""Fuzzing the session reader and writer (issue 8 / 17).

Properties:
- ``read_session`` raises only SessionError, whatever the bytes;
- damage never costs an intact pose line before it (nor, for whole-line damage, after it);
- with the header intact, the default (salvaging) reader never fails;
- the writer never writes a line the reader rejects, and refuses without writing anything.

CI runs a small budget; ``pytest --fuzz-long`` runs ≥ 10⁵ examples per test.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.errors import SessionError
from tmscal.session import (
    PoseRecord,
    SessionWriter,
    make_header,
    read_session,
    records_from_arrays,
    write_session,
)
from tmscal.sim import Noise, simulate

_TRUTH, _D = simulate(6, np.random.default_rng(3), plan="eq14", noise=Noise())
_HEADER = make_header(["marker", "probe"], truth=_TRUTH.as_dict(), plan={"kind": "eq14"})
_RECS = records_from_arrays(_D["A"], _D["marker"], _D["probe"], _D["commanded"], samples=10)
for _r in _RECS:
    _r.spread = {"marker": {"trans_mm": 0.03, "rot_deg": 0.01}}
_RECS[4].skipped, _RECS[4].B, _RECS[4].C = "probe usable in 3 of 10 frames", None, None

_DIR = Path(tempfile.mkdtemp(prefix="tmscal-fuzz-"))
_GOOD = write_session(_DIR / "good.jsonl", _HEADER, _RECS).read_bytes()
_LINES = _GOOD.split(b"\n")[:-1]  # header + 6 pose lines, each without its newline

_SETTINGS = dict(suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                        HealthCheck.filter_too_much,
                                        HealthCheck.function_scoped_fixture])


def _read(raw: bytes, strict: bool = False):
    """read_session on raw bytes: the Session, or the SessionError; anything else escapes
    (and fails the test)."""
    fd, name = tempfile.mkstemp(dir=_DIR, suffix=".jsonl")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
        try:
            return read_session(name, strict=strict)
        except SessionError as e:
            assert name in str(e)  # names the file
            return e
    finally:
        os.unlink(name)


def _intact_lines_before(raw: bytes) -> list[int]:
    """Pose numbers (0-based into _RECS) whose whole original line, newline included, lies
    before the first byte where ``raw`` differs from the good session."""
    k = next((i for i, (a, b) in enumerate(zip(raw, _GOOD, strict=False)) if a != b),
             min(len(raw), len(_GOOD)))
    out, end = [], 0
    for no, line in enumerate(_LINES):
        end += len(line) + 1
        if end <= k and no > 0:
            out.append(no - 1)
    return out


def _same(rec: PoseRecord, want: PoseRecord) -> bool:
    return (rec.index == want.index and rec.skipped == want.skipped
            and all((getattr(rec, m) is None and getattr(want, m) is None)
                    or np.array_equal(getattr(rec, m), getattr(want, m))
                    for m in ("A", "B", "C", "commanded")))


def _check_result(s, raw: bytes) -> None:
    """The invariants of any successful read."""
    if isinstance(s, SessionError):
        assert not raw.startswith(_LINES[0] + b"\n"), f"intact header, yet: {s}"
        return
    idx = [r.index for r in s.poses]
    assert len(idx) == len(set(idx))
    for r in s.poses:
        for m in (r.A, r.B, r.C, r.commanded):
            assert m is None or (m.shape == (4, 4) and np.isfinite(m).all())
        assert math.isfinite(r.time)
    assert all(isinstance(no, int) and no >= 2 and isinstance(why, str) for no, why in s.damaged)
    assert 0 <= s.good_bytes <= len(raw)
    by_index = {r.index: r for r in s.poses}
    for i in _intact_lines_before(raw):
        assert i in by_index and _same(by_index[i], _RECS[i]), f"intact pose {i} lost"


@fuzz_settings(200, **_SETTINGS)
@given(blob=st.binary(max_size=400))
def test_random_bytes_only_session_error(blob):
    s = _read(blob)
    assert isinstance(s, SessionError) or s.header["format"] == "tmscal-session"


@fuzz_settings(200, **_SETTINGS)
@given(tail=st.binary(max_size=400))
def test_random_bytes_after_a_header_never_fail(tail):
    raw = _LINES[0] + b"\n" + tail
    _check_result(_read(raw), raw)
    s = _read(raw, strict=True)
    assert isinstance(s, SessionError) or not s.damaged


_MUTATIONS = ["flip", "flips", "truncate", "insert", "delete", "dup_line", "drop_line",
              "swap_lines", "garbage_line", "crlf", "nul_tail"]


@fuzz_settings(300, **_SETTINGS)
@given(data=st.data(), kind=st.sampled_from(_MUTATIONS))
def test_mutated_sessions_keep_every_intact_pose_before_the_damage(data, kind):
    raw = bytearray(_GOOD)
    lines = list(_LINES)
    pick_line = st.integers(1, len(lines) - 1)
    if kind == "flip":
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.integers(0, 255))
    elif kind == "flips":
        for i in data.draw(st.lists(st.integers(0, len(raw) - 1), min_size=2, max_size=6)):
            raw[i] ^= 1 << data.draw(st.integers(0, 7))
    elif kind == "truncate":
        raw = raw[: data.draw(st.integers(0, len(raw)))]
    elif kind == "insert":
        i = data.draw(st.integers(0, len(raw)))
        raw[i:i] = data.draw(st.binary(min_size=1, max_size=12))
    elif kind == "delete":
        i = data.draw(st.integers(0, len(raw) - 1))
        del raw[i:i + data.draw(st.integers(1, 40))]
    elif kind == "dup_line":
        i = data.draw(pick_line)
        lines.insert(data.draw(st.integers(i + 1, len(lines))), lines[i])
        raw = bytearray(b"\n".join(lines) + b"\n")
    elif kind == "drop_line":
        del lines[data.draw(pick_line)]
        raw = bytearray(b"\n".join(lines) + b"\n")
    elif kind == "swap_lines":
        i, j = data.draw(pick_line), data.draw(pick_line)
        lines[i], lines[j] = lines[j], lines[i]
        raw = bytearray(b"\n".join(lines) + b"\n")
    elif kind == "garbage_line":
        lines.insert(data.draw(st.integers(1, len(lines))), data.draw(st.binary(max_size=60))
                     .replace(b"\n", b" "))
        raw = bytearray(b"\n".join(lines) + b"\n")
    elif kind == "crlf":
        raw = bytearray(_GOOD.replace(b"\n", b"\r\n"))
    else:  # a power cut: the file grew but the last blocks are zeros
        raw += b"\0" * data.draw(st.integers(1, 600))
    raw = bytes(raw)
    s = _read(raw)
    _check_result(s, raw)
    if kind in ("dup_line", "swap_lines", "crlf", "nul_tail"):
        # whole lines moved or repeated, nothing destroyed: every pose is still there
        assert sorted(r.index for r in s.poses) == list(range(len(_RECS)))
        assert not s.torn_tail or kind == "nul_tail"
    if kind in ("drop_line", "garbage_line"):
        assert len(s.poses) >= len(_RECS) - (kind == "drop_line")
    strict = _read(raw, strict=True)
    assert isinstance(strict, SessionError) or (not strict.damaged
                                                and strict.indices() == s.indices())


# --- JSON value substitution ---------------------------------------------------------------

_HUGE_INT = "1" + "0" * 400
_SENTINEL = "__FUZZ_RAW__"
_RAW_VALUES = ["NaN", "Infinity", "-Infinity", "1e400", "-1e999", _HUGE_INT, "1" * 5000,
               "[" * 3000 + "]" * 3000, "[" * 50_000, '"\\udc80"', '"\\ud800x"', "1e308",
               "-0.0", "true", "null", "{}", "[]", '""', "[[1e308,0,0,0],[0,1,0,0],[0,0,1,0],"
               "[0,0,0,1]]", "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1],[0,0,0,1]]"]


def _paths(obj, prefix=()):
    """Every path (tuple of keys / indices) in a JSON value."""
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, (*prefix, i))


def _substitute(line: bytes, path: tuple, raw_value: str) -> bytes:
    obj = json.loads(line)
    if not path:
        return raw_value.encode()
    parent = obj
    for k in path[:-1]:
        parent = parent[k]
    parent[path[-1]] = _SENTINEL
    return json.dumps(obj, separators=(",", ":")).replace(f'"{_SENTINEL}"', raw_value).encode()


@fuzz_settings(300, **_SETTINGS)
@given(data=st.data())
def test_substituted_json_values(data):
    no = data.draw(st.integers(0, len(_LINES) - 1))
    paths = list(_paths(json.loads(_LINES[no])))
    path = data.draw(st.sampled_from(paths))
    value = data.draw(st.one_of(st.sampled_from(_RAW_VALUES),
                                st.from_type(int).map(str),
                                st.floats(allow_nan=False, allow_infinity=False).map(repr),
                                st.text(max_size=8).map(json.dumps)))
    lines = list(_LINES)
    lines[no] = _substitute(lines[no], path, value)
    raw = b"\n".join(lines) + b"\n"
    s = _read(raw)
    if no == 0:
        assert isinstance(s, SessionError) or s.indices() == set(range(len(_RECS)))
        return
    assert not isinstance(s, SessionError), s
    _check_result(s, raw)
    n = len(_RECS)
    intact = {r.index for r in s.poses if r.index < n and _same(r, _RECS[r.index])}
    changed = [r for r in s.poses if r.index not in intact]
    assert len(changed) <= 1 and len(s.damaged) <= 1
    # only the substituted line's own pose, or the one whose index it took, can be missing
    assert set(range(n)) - {no - 1} - intact <= {r.index for r in changed}
    strict = _read(raw, strict=True)
    if s.damaged:
        assert isinstance(strict, SessionError)
        assert f"line {s.damaged[0][0]}: " in str(strict)
    else:
        assert not isinstance(strict, SessionError) and strict.indices() == s.indices()


# --- the writer never writes what the reader rejects ----------------------------------------

_weird_floats = st.one_of(st.floats(), st.sampled_from([1e308, -1e308, 1e-320, 0.0, 1.0]))


@st.composite
def _records(draw) -> PoseRecord:
    i = draw(st.integers(0, len(_RECS) - 1))
    rec = records_from_arrays(_D["A"], _D["marker"], _D["probe"], _D["commanded"])[i]
    field = draw(st.sampled_from(["A", "B", "C", "commanded", "time", "samples", "spread",
                                  "index", "skipped", "none"]))
    if field in ("A", "B", "C", "commanded"):
        M = np.array(getattr(rec, field))
        for _ in range(draw(st.integers(1, 3))):
            M[draw(st.integers(0, 3)), draw(st.integers(0, 3))] = draw(_weird_floats)
        setattr(rec, field, M)
    elif field == "time":
        rec.time = draw(_weird_floats)
    elif field == "samples":
        rec.samples = draw(st.dictionaries(st.text(max_size=3), st.one_of(
            st.integers(-5, 2 ** 70), _weird_floats, st.none(), st.text(max_size=3)),
            max_size=3))
    elif field == "spread":
        rec.spread = draw(st.dictionaries(st.text(max_size=3), st.one_of(
            st.dictionaries(st.text(max_size=3), _weird_floats, max_size=2),
            _weird_floats, st.lists(st.integers(), max_size=2)), max_size=3))
    elif field == "index":
        rec.index = draw(st.integers(-3, 2 ** 70))
    elif field == "skipped":
        rec.skipped = draw(st.one_of(st.text(max_size=10), st.integers()))
    return rec


@fuzz_settings(200, **_SETTINGS)
@given(rec=_records())
def test_writer_writes_only_what_reads_back(rec):
    fd, name = tempfile.mkstemp(dir=_DIR, suffix=".jsonl")
    os.close(fd)
    os.unlink(name)
    try:
        with SessionWriter.create(name, _HEADER) as w:
            before = Path(name).read_bytes()
            try:
                w.append(rec)
            except SessionError as e:
                assert "pose" in str(e)
                assert Path(name).read_bytes() == before  # nothing written
                assert not w.session.poses
                return
        s = read_session(name, strict=True)
        assert len(s.poses) == 1 and s.poses[0].index == int(rec.index)
        for m in ("A", "B", "C", "commanded"):
            want = getattr(rec, m)
            got = getattr(s.poses[0], m)
            assert (want is None and got is None) or np.array_equal(got, want)
    finally:
        if os.path.exists(name):
            os.unlink(name)
