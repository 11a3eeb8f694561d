"""Property tests of the ATI Net F/T RDT codec: round trips, and every input of any length
either parses or fails with the one typed error."""

from __future__ import annotations

import struct

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.drivers.ati import codec
from tmscal.errors import ProtocolError

u32 = st.integers(0, 2**32 - 1)
i32 = st.integers(-(2**31), 2**31 - 1)


@fuzz_settings()
@given(u32, u32, u32, st.tuples(i32, i32, i32, i32, i32, i32))
def test_record_round_trip(seq: int, ft: int, status: int, counts: tuple[int, ...]) -> None:
    rec = codec.Record(seq, ft, status, counts)  # type: ignore[arg-type]
    data = codec.pack_record(rec)
    assert len(data) == 36
    assert codec.parse_record(data) == rec


@fuzz_settings()
@given(st.binary(min_size=36, max_size=36))
def test_any_36_bytes_parse_to_a_record(data: bytes) -> None:
    rec = codec.parse_record(data)
    assert codec.pack_record(rec) == data


@fuzz_settings()
@given(st.binary(max_size=200).filter(lambda b: len(b) != 36))
def test_any_other_length_is_refused(data: bytes) -> None:
    try:
        codec.parse_record(data)
    except ProtocolError as e:
        assert f"length {len(data)} bytes" in str(e)
    else:
        raise AssertionError("a record of the wrong length parsed")


@fuzz_settings()
@given(st.binary(max_size=20))
def test_any_request_bytes_parse_or_one_typed_error(data: bytes) -> None:
    try:
        command, count = codec.parse_request(data)
    except ProtocolError:
        return
    assert len(data) == 8 and data[:2] == b"\x12\x34"
    assert command in codec.COMMANDS
    assert codec.pack_request(command, count) == data


@fuzz_settings()
@given(st.sampled_from(sorted(codec.COMMANDS)), u32)
def test_request_round_trip(command: int, count: int) -> None:
    data = codec.pack_request(command, count)
    assert struct.unpack(">HHI", data) == (0x1234, command, count)
    assert codec.parse_request(data) == (command, count)


finite = st.floats(-100.0, 100.0, allow_nan=False)   # × 1e7 counts per unit < 2³¹


@fuzz_settings()
@given(st.lists(finite, min_size=6, max_size=6), st.floats(1e2, 1e7), st.floats(1e2, 1e7))
def test_counts_round_trip_within_one_count(w: list[float], cpf: float, cpt: float) -> None:
    c = codec.counts_from_wrench(np.array(w), cpf, cpt)
    back = codec.wrench_from_counts(c, cpf, cpt)
    scale = np.array([cpf] * 3 + [cpt] * 3)
    assert np.all(np.abs(back - np.array(w)) * scale <= 0.5 + 1e-6)
