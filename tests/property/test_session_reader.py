"""Damaged session files: the reader raises SessionError or returns the intact poses, never
anything else (more in ``test_session_fuzz.py``)."""

import numpy as np
from hypothesis import HealthCheck, given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.errors import SessionError
from tmscal.session import make_header, read_session, records_from_arrays, write_session
from tmscal.sim import Noise, simulate

_SLOW_OK = [HealthCheck.function_scoped_fixture]
_, _D = simulate(4, np.random.default_rng(0), plan="eq14", noise=Noise())


def _good(tmp_path):
    p = tmp_path / "base.jsonl"
    if not p.exists():
        write_session(p, make_header(["marker", "probe"]),
                      records_from_arrays(_D["A"], _D["marker"], _D["probe"]))
    return p.read_bytes()


@fuzz_settings(200, suppress_health_check=_SLOW_OK)
@given(data=st.data())
def test_mutated_sessions(tmp_path, data):
    raw = bytearray(_good(tmp_path))
    kind = data.draw(st.sampled_from(["truncate", "flip", "insert", "delete"]))
    i = data.draw(st.integers(0, len(raw) - 1))
    if kind == "truncate":
        raw = raw[:i]
    elif kind == "flip":
        raw[i] = data.draw(st.integers(0, 255))
    elif kind == "insert":
        raw[i:i] = data.draw(st.binary(min_size=1, max_size=8))
    else:
        del raw[i:i + data.draw(st.integers(1, 20))]
    p = tmp_path / "m.jsonl"
    p.write_bytes(bytes(raw))
    try:
        s = read_session(p)
    except SessionError:
        return
    for rec in s.poses:
        assert rec.A is None or rec.A.shape == (4, 4)
    # nothing is lost before the first changed byte
    good = _good(tmp_path)
    k = next((j for j, (a, b) in enumerate(zip(raw, good, strict=False)) if a != b),
             min(len(raw), len(good)))  # a longer file equal up to the end changed after it
    intact = raw[:k].count(b"\n") - 1  # whole pose lines before the change
    assert {r.index for r in s.poses} >= set(range(max(0, intact)))


@fuzz_settings(100, suppress_health_check=_SLOW_OK)
@given(blob=st.binary(max_size=300))
def test_random_bytes(tmp_path, blob):
    p = tmp_path / "r.jsonl"
    p.write_bytes(blob)
    try:
        read_session(p)
    except SessionError:
        pass
