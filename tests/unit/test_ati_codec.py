"""The ATI Net F/T RDT codec against golden bytes written out by hand from the layout in
ATI's Net F/T manual (request ``>HHI``, record ``>IIIiiiiii``, big-endian)."""

from __future__ import annotations

import numpy as np
import pytest

from tmscal.drivers.ati import codec
from tmscal.errors import DeviceError, ProtocolError

#: START_REALTIME for 10 records: header 0x1234, command 0x0002, count 10
GOLDEN_REQUEST = bytes.fromhex("1234 0002 0000000a")
#: rdt_sequence 1, ft_sequence 7, status 0, Fx 1,000,000, Fy −2,000,000, Fz 3, Tx −4, Tz 5,
#: Tz 2³¹−1
GOLDEN_RECORD = bytes.fromhex("00000001 00000007 00000000 000f4240 ffe17b80 00000003 "
                              "fffffffc 00000005 7fffffff")


def test_request_golden_bytes() -> None:
    assert codec.pack_request(codec.START_REALTIME, 10) == GOLDEN_REQUEST
    assert codec.parse_request(GOLDEN_REQUEST) == (0x0002, 10)
    assert codec.pack_request(codec.STOP) == bytes.fromhex("12340000 00000000")
    assert codec.pack_request(codec.SET_SOFTWARE_BIAS) == bytes.fromhex("12340042 00000000")


def test_record_golden_bytes() -> None:
    rec = codec.parse_record(GOLDEN_RECORD)
    assert (rec.rdt_sequence, rec.ft_sequence, rec.status) == (1, 7, 0)
    assert rec.counts == (1_000_000, -2_000_000, 3, -4, 5, 2**31 - 1)
    assert codec.pack_record(rec) == GOLDEN_RECORD


def test_counts_to_units_divide_by_the_calibration() -> None:
    """Forces by counts per N, torques by counts per N·m (an ATI Mini40-like 1e6/1e6 would
    hide a swap; these differ)."""
    w = codec.wrench_from_counts(np.array([1_000_000, -2_000_000, 3, -4, 5, 6]), 1e6, 2e3)
    np.testing.assert_allclose(w, [1.0, -2.0, 3e-6, -0.002, 0.0025, 0.003])
    back = codec.counts_from_wrench(w, 1e6, 2e3)
    np.testing.assert_array_equal(back, [1_000_000, -2_000_000, 3, -4, 5, 6])


def test_counts_saturate_at_int32() -> None:
    c = codec.counts_from_wrench(np.array([1e9, -1e9, 0, 0, 0, 0]), 1e6, 1e6)
    assert c[0] == 2**31 - 1 and c[1] == -(2**31)


@pytest.mark.parametrize("cpf", [0, -1.0, float("nan"), float("inf"), True, "1e6"])
def test_bad_counts_per_unit_refused(cpf: object) -> None:
    with pytest.raises(ValueError, match="counts_per_force"):
        codec.wrench_from_counts(np.zeros(6), cpf, 1e6)  # type: ignore[arg-type]


@pytest.mark.parametrize("data, field", [
    (GOLDEN_REQUEST[:7], "length 7"),
    (GOLDEN_REQUEST + b"\0", "length 9"),
    (bytes.fromhex("4321 0002 0000000a"), "header 0x4321"),
    (bytes.fromhex("1234 0005 00000000"), "unknown command 0x0005"),
])
def test_bad_requests_name_the_field(data: bytes, field: str) -> None:
    with pytest.raises(ProtocolError, match=field) as e:
        codec.parse_request(data)
    assert isinstance(e.value, DeviceError) and e.value.device == "ati"


@pytest.mark.parametrize("n", [0, 35, 37, 72])
def test_record_of_wrong_length_refused(n: int) -> None:
    with pytest.raises(ProtocolError, match=f"length {n} bytes, expected 36"):
        codec.parse_record(bytes(n))


def test_pack_request_refuses_unknown_command_and_count() -> None:
    with pytest.raises(ValueError, match="0x0007"):
        codec.pack_request(7)
    with pytest.raises(ValueError, match="sample count"):
        codec.pack_request(codec.START_REALTIME, 2**32)


def test_status_described_by_bits() -> None:
    assert codec.describe_status(0) == "healthy"
    text = codec.describe_status(0x80000005)
    assert text.startswith("status 0x80000005")
    assert "bit 31 (error summary)" in text and "bit 2" in text and "bit 0" in text
    assert "bit 1" not in text


@pytest.mark.parametrize("prev, cur, step", [
    (1, 2, 1), (1, 5, 4), (5, 3, -2), (5, 5, 0), (2**32 - 1, 0, 1), (2**32 - 2, 1, 3),
    (0, 2**32 - 1, -1),
])
def test_sequence_step_wraps(prev: int, cur: int, step: int) -> None:
    assert codec.sequence_step(prev, cur) == step
