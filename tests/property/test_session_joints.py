"""The optional per-pose fields joints_rad (rad), wrench and wrench_spread ([F N, τ N·m]):
whatever JSON value a pose line carries in them, the reader returns exactly the numbers it
stored or refuses the line naming the field, and the writer accepts exactly what the reader
will (tmscal.session.records; docs/session-format.md)."""

from __future__ import annotations

import json
import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.errors import SessionError
from tmscal.session import PoseRecord, validate_record
from tmscal.session.records import BadLine, validate_pose

_FIELDS = ("joints_rad", "wrench", "wrench_spread")
_numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**400,
                                                                                 10**400))
_values = st.one_of(
    st.none(), st.lists(_numbers, max_size=40), st.lists(st.floats(-1e7, 1e7), min_size=6,
                                                         max_size=6),
    st.lists(st.floats(-10.0, 10.0), min_size=1, max_size=8),
    st.text(max_size=5), st.booleans(), st.dictionaries(st.text(max_size=3), _numbers,
                                                        max_size=2),
    st.lists(st.lists(st.floats(-1, 1), max_size=3), max_size=3))


def _line(field: str, value: object) -> dict:
    return {"kind": "pose", "index": 3, "time": 1.0, "A": np.eye(4).tolist(), field: value}


def _acceptable(field: str, value: object) -> bool:
    """The documented rule, written independently of the reader."""
    if value is None:
        return True
    if type(value) is not list or not all(type(x) in (int, float) for x in value):
        return False
    ok_len = 1 <= len(value) <= 32 if field == "joints_rad" else len(value) == 6
    bound = 1e3 if field == "joints_rad" else 1e6
    vals = []
    for x in value:
        try:
            vals.append(float(x))
        except OverflowError:
            return False
    return ok_len and all(math.isfinite(v) and abs(v) < bound for v in vals) and (
        field != "wrench_spread" or all(v >= 0 for v in vals))


@fuzz_settings(300)
@given(field=st.sampled_from(_FIELDS), value=_values)
def test_reader_keeps_the_numbers_or_names_the_field(field, value):
    try:
        rec = validate_pose(json.loads(json.dumps(_line(field, value))))
    except BadLine as e:
        assert not _acceptable(field, value)
        assert f"'{field}'" in str(e)
        return
    except (ValueError, OverflowError):   # json.dumps of NaN is valid Python JSON only
        return
    assert _acceptable(field, value)
    got = getattr(rec, field)
    assert got == (None if value is None else [float(x) for x in value])


@fuzz_settings(200)
@given(field=st.sampled_from(_FIELDS), value=_values)
def test_writer_accepts_what_the_reader_will(field, value):
    rec = PoseRecord(index=5, A=np.eye(4), B=np.eye(4), **{field: value})
    try:
        back = validate_record(rec)
    except SessionError as e:
        assert "pose 5" in str(e) and field in str(e)
        assert not _acceptable(field, value)
        return
    got = getattr(back, field)
    assert got is None or got == [float(x) for x in value]
    assert got is None or _acceptable(field, got)
