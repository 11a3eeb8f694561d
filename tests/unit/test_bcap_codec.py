"""b-CAP codec: the protocol sheet's golden packets, hand-built VARIANT bytes, round trips,
DENSO-client-style mapping, and every validation error."""

from __future__ import annotations

import datetime as dt
import struct
from decimal import Decimal

import pytest

from tmscal.drivers.denso.hresult import (
    E_BUSY_PROC,
    E_INVALIDPACKET,
    S_OK,
    hresult_name,
)
from tmscal.drivers.denso.packet import (
    MAX_ARGUMENTS,
    MAX_PACKET_SIZE,
    Fn,
    PacketFramer,
    decode_packet,
    encode_packet,
    frame_serial,
    function_name,
    next_serial,
)
from tmscal.drivers.denso.variant import (
    MAX_ARRAY_ELEMENTS,
    MAX_NESTING,
    MAX_VARIANTS,
    VT_ARRAY,
    VT_BOOL,
    VT_BSTR,
    VT_CY,
    VT_DATE,
    VT_EMPTY,
    VT_ERROR,
    VT_I2,
    VT_I4,
    VT_I8,
    VT_NULL,
    VT_R4,
    VT_R8,
    VT_UI1,
    VT_UI2,
    VT_UI4,
    VT_UI8,
    VT_VARIANT,
    Variant,
    date_from_datetime,
    decode_variant,
    encode_variant,
    to_variant,
)
from tmscal.errors import ProtocolError

# golden vectors from DENSO's b-CAP specification, checked against DENSO's own Python client
SERVICE_STOP = bytes.fromhex("01 10 00 00 00 02 00 00 00 02 00 00 00 00 00 04")
HANDLE_7_REPLY = bytes.fromhex(
    "01 1e 00 00 00 03 00 00 00 00 00 00 00 01 00 0a 00 00 00 03 00 01 00 00 00 07 00 00 00 04")


def test_golden_service_stop_encode_and_decode() -> None:
    assert encode_packet(2, Fn.SERVICE_STOP) == SERVICE_STOP
    p = decode_packet(SERVICE_STOP)
    assert (p.serial, p.code, p.args, p.reserved) == (2, 2, (), 0)


def test_golden_handle_reply_encode_and_decode() -> None:
    assert encode_packet(3, S_OK, [Variant(VT_I4, 7)]) == HANDLE_7_REPLY
    assert encode_packet(3, S_OK, [7]) == HANDLE_7_REPLY  # int → I4 like DENSO's client
    p = decode_packet(HANDLE_7_REPLY)
    assert p.serial == 3 and p.code == 0 and not p.failed
    assert p.args == (Variant(VT_I4, 7),)


def h(s: str) -> bytes:
    return bytes.fromhex(s)


HAND_BUILT = [
    (Variant(VT_EMPTY), "00 00 01 00 00 00"),
    (Variant(VT_NULL), "01 00 01 00 00 00"),
    (Variant(VT_I2, -2), "02 00 01 00 00 00 fe ff"),
    (Variant(VT_I4, 7), "03 00 01 00 00 00 07 00 00 00"),
    (Variant(VT_R4, 1.5), "04 00 01 00 00 00 00 00 c0 3f"),
    (Variant(VT_R8, 1.5), "05 00 01 00 00 00 00 00 00 00 00 00 f8 3f"),
    (Variant(VT_CY, Decimal("1.5")), "06 00 01 00 00 00 98 3a 00 00 00 00 00 00"),
    (Variant(VT_DATE, 2.0), "07 00 01 00 00 00 00 00 00 00 00 00 00 40"),
    (Variant(VT_BSTR, "P"), "08 00 01 00 00 00 02 00 00 00 50 00"),
    (Variant(VT_ERROR, 0x80010000), "0a 00 01 00 00 00 00 00 01 80"),
    (Variant(VT_BOOL, True), "0b 00 01 00 00 00 ff ff"),
    (Variant(VT_BOOL, False), "0b 00 01 00 00 00 00 00"),
    (Variant(VT_VARIANT, Variant(VT_I2, 1)), "0c 00 01 00 00 00 02 00 01 00 00 00 01 00"),
    (Variant(VT_UI1, 255), "11 00 01 00 00 00 ff"),
    (Variant(VT_UI2, 0xABCD), "12 00 01 00 00 00 cd ab"),
    (Variant(VT_UI4, 0xDEADBEEF), "13 00 01 00 00 00 ef be ad de"),
    (Variant(VT_I8, -1), "14 00 01 00 00 00 ff ff ff ff ff ff ff ff"),
    (Variant(VT_UI8, 1 << 63), "15 00 01 00 00 00 00 00 00 00 00 00 00 80"),
    (Variant(VT_I4 | VT_ARRAY, [1, -1]), "03 20 02 00 00 00 01 00 00 00 ff ff ff ff"),
    (Variant(VT_BSTR | VT_ARRAY, ["P", "@P"]),
     "08 20 02 00 00 00 02 00 00 00 50 00 04 00 00 00 40 00 50 00"),
    (Variant(VT_UI1 | VT_ARRAY, b"\x01\x02"), "11 20 02 00 00 00 01 02"),
    (Variant(VT_BOOL | VT_ARRAY, [True, False]), "0b 20 02 00 00 00 ff ff 00 00"),
    (Variant(VT_VARIANT | VT_ARRAY, [Variant(VT_R8, 1.5), Variant(VT_BSTR, "P")]),
     "0c 20 02 00 00 00 05 00 01 00 00 00 00 00 00 00 00 00 f8 3f "
     "08 00 01 00 00 00 02 00 00 00 50 00"),
    (Variant(VT_VARIANT | VT_ARRAY, []), "0c 20 00 00 00 00"),
]


@pytest.mark.parametrize("v,hexbytes", HAND_BUILT, ids=[repr(v) for v, _ in HAND_BUILT])
def test_variant_hand_built_bytes_both_ways(v: Variant, hexbytes: str) -> None:
    assert encode_variant(v) == h(hexbytes)
    back, end = decode_variant(h(hexbytes))
    assert back == v
    assert end == len(h(hexbytes))


ROUND_TRIP = [
    Variant(VT_I2 | VT_ARRAY, [-32768, 32767]),
    Variant(VT_R4 | VT_ARRAY, [0.25, -2.0]),
    Variant(VT_R8 | VT_ARRAY, [100.0, -0.5, 1e300]),
    Variant(VT_CY | VT_ARRAY, [Decimal("-0.0001"), Decimal("922337203685477.5807")]),
    Variant(VT_DATE | VT_ARRAY, [45000.5]),
    Variant(VT_ERROR | VT_ARRAY, [0, 0xFFFFFFFF]),
    Variant(VT_UI2 | VT_ARRAY, [0, 65535]),
    Variant(VT_UI4 | VT_ARRAY, [4294967295]),
    Variant(VT_I8 | VT_ARRAY, [-(1 << 63)]),
    Variant(VT_UI8 | VT_ARRAY, [(1 << 64) - 1]),
    Variant(VT_BSTR, "Grüße, 東京 🙂"),
    Variant(VT_BSTR | VT_ARRAY, ["", "a", "@CURRENT_POSITION"]),
    Variant(VT_UI1 | VT_ARRAY, bytes(range(256))),
    Variant(VT_VARIANT | VT_ARRAY, [Variant(VT_VARIANT | VT_ARRAY, [Variant(VT_EMPTY)]),
                                    Variant(VT_UI1 | VT_ARRAY, b""), Variant(VT_NULL)]),
]


@pytest.mark.parametrize("v", ROUND_TRIP, ids=repr)
def test_variant_round_trip(v: Variant) -> None:
    enc = encode_variant(v)
    back, end = decode_variant(enc)
    assert back == v and end == len(enc)
    # and inside a packet
    p = decode_packet(encode_packet(9, Fn.ROBOT_EXECUTE, [v, Variant(VT_I4, 1)]))
    assert p.args == (v, Variant(VT_I4, 1))


def test_bstr_is_utf16le_with_byte_length() -> None:
    assert encode_variant(Variant(VT_BSTR, "é")) == h("08 00 01 00 00 00 02 00 00 00 e9 00")
    assert encode_variant(Variant(VT_BSTR, "")) == h("08 00 01 00 00 00 00 00 00 00")


def test_date_helper() -> None:
    assert date_from_datetime(dt.datetime(1900, 1, 1, 12)) == 2.5
    assert to_variant(dt.datetime(1899, 12, 31)) == Variant(VT_DATE, 1.0)


# --- DENSO-client-style mapping -------------------------------------------------------------

def test_to_variant_scalars_like_denso_client() -> None:
    assert to_variant(5) == Variant(VT_I4, 5)
    assert to_variant(2.5) == Variant(VT_R8, 2.5)
    assert to_variant("Arm") == Variant(VT_BSTR, "Arm")
    assert to_variant(True) == Variant(VT_BOOL, True)
    assert to_variant(None) == Variant(VT_EMPTY, None)
    assert to_variant(b"\x00\x01") == Variant(VT_UI1 | VT_ARRAY, b"\x00\x01")
    assert to_variant(1 << 40) == Variant(VT_I8, 1 << 40)


def test_to_variant_lists() -> None:
    assert to_variant([0, 0]) == Variant(VT_I4 | VT_ARRAY, [0, 0])
    assert to_variant([1.0, 2.0]) == Variant(VT_R8 | VT_ARRAY, [1.0, 2.0])
    assert to_variant(["a", "b"]) == Variant(VT_BSTR | VT_ARRAY, ["a", "b"])
    assert to_variant([1, "a"]) == Variant(VT_VARIANT | VT_ARRAY,
                                           [Variant(VT_I4, 1), Variant(VT_BSTR, "a")])
    assert encode_variant(to_variant([0, 0])) == h(
        "03 20 02 00 00 00 00 00 00 00 00 00 00 00")  # TakeArm [0, 0]


def test_pose_with_int_fig_goes_out_as_nested_variant_array() -> None:
    v = to_variant([[100.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1], "P", "@P"])
    r8 = lambda x: "05 00 01 00 00 00 " + struct.pack("<d", x).hex(" ")  # noqa: E731
    expected = ("0c 20 03 00 00 00 "
                "0c 20 07 00 00 00 " + r8(100.0) + " " + " ".join([r8(0.0)] * 5)
                + " 03 00 01 00 00 00 ff ff ff ff "
                "08 00 01 00 00 00 02 00 00 00 50 00 "
                "08 00 01 00 00 00 04 00 00 00 40 00 50 00")
    assert encode_variant(v) == h(expected)
    assert v.to_python() == [[100.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1], "P", "@P"]


def test_encode_rejects_values_that_do_not_fit() -> None:
    for v in (Variant(VT_I2, 40000), Variant(VT_UI1, -1), Variant(VT_I4, 1.5),
              Variant(VT_BOOL, 1), Variant(VT_BSTR, 3), Variant(VT_CY, Decimal("0.00001")),
              Variant(0x2000 | 0x99, [1]), Variant(VT_VARIANT | VT_ARRAY, [1])):
        with pytest.raises(ValueError):
            encode_variant(v)
    with pytest.raises(ValueError):
        to_variant(object())


# --- packet validation -------------------------------------------------------------------

def _bad(data: bytes, match: str) -> None:
    with pytest.raises(ProtocolError, match=match) as ei:
        decode_packet(data)
    assert ei.value.code == E_INVALIDPACKET == 0x80010000


def test_wrong_soh() -> None:
    _bad(b"\x02" + SERVICE_STOP[1:], "SOH")


def test_wrong_eot() -> None:
    _bad(SERVICE_STOP[:-1] + b"\x05", "EOT")


def test_length_field_disagrees() -> None:
    _bad(HANDLE_7_REPLY[:1] + struct.pack("<I", 29) + HANDLE_7_REPLY[5:], "length field 29")
    _bad(HANDLE_7_REPLY + b"\x04", "length field 30")


def test_truncated() -> None:
    _bad(SERVICE_STOP[:10], "truncated")
    # argument count says 2 but only one argument present (length fixed up)
    body = bytearray(HANDLE_7_REPLY)
    body[13] = 2
    _bad(bytes(body), "argument 2 of 2 missing")


def test_argument_length_disagrees_with_variant() -> None:
    body = bytearray(HANDLE_7_REPLY)
    body[15] = 0x09  # says 9 bytes, the I4 VARIANT has 10
    _bad(bytes(body), "argument 1")


def test_unknown_vt_and_bad_bstr() -> None:
    with pytest.raises(ProtocolError, match="unsupported"):
        decode_variant(h("63 00 01 00 00 00 00"))
    with pytest.raises(ProtocolError, match="odd"):
        decode_variant(h("08 00 01 00 00 00 01 00 00 00 50"))
    with pytest.raises(ProtocolError, match="truncated"):
        decode_variant(h("05 20 ff ff ff ff 00"))  # 4 billion doubles claimed


def test_negative_hresult_encodes_as_unsigned() -> None:
    a = encode_packet(1, E_BUSY_PROC)
    b = encode_packet(1, E_BUSY_PROC - (1 << 32))
    assert a == b and a[9:13] == h("aa 00 91 80")
    assert decode_packet(a).code == 0x809100AA and decode_packet(a).failed


# --- framer ----------------------------------------------------------------------------------

def test_framer_byte_by_byte() -> None:
    f = PacketFramer()
    out = []
    for b in SERVICE_STOP + HANDLE_7_REPLY:
        f.feed(bytes([b]))
        while (p := f.next_packet()) is not None:
            out.append(p)
    assert [(p.serial, p.code) for p in out] == [(2, 2), (3, 0)]
    assert f.buffered == 0


def test_framer_resyncs_after_garbage() -> None:
    f = PacketFramer()
    f.feed(b"\xffgarbage" + HANDLE_7_REPLY)
    with pytest.raises(ProtocolError, match="SOH"):
        f.next_packet()
    assert f.next_packet() == decode_packet(HANDLE_7_REPLY)
    assert f.next_packet() is None


def test_framer_rejects_bad_length_and_eot() -> None:
    f = PacketFramer(max_size=1000)
    f.feed(b"\x01" + struct.pack("<I", 5000) + b"\x00" * 20)
    with pytest.raises(ProtocolError, match="length field 5000"):
        f.next_frame()
    f = PacketFramer()
    f.feed(SERVICE_STOP[:-1] + b"\x00")
    with pytest.raises(ProtocolError, match="EOT"):
        f.next_frame()


# --- serials, HRESULTs ------------------------------------------------------------------------

def test_serial_wraps_to_one_never_zero() -> None:
    assert next_serial(0) == 1
    assert next_serial(1) == 2
    assert next_serial(0xFFFE) == 0xFFFF
    assert next_serial(0xFFFF) == 1
    s, seen = 0, set()
    for _ in range(70000):
        s = next_serial(s)
        seen.add(s)
    assert 0 not in seen and seen == set(range(1, 0x10000))


def test_hresult_names() -> None:
    assert hresult_name(0x81501003) == "motor off"
    assert hresult_name(0x83500178) == "not executable during emergency stop"
    assert hresult_name(0x809100AA) == "E_BUSY_PROC"
    assert hresult_name(0x80010000) == "E_INVALIDPACKET"
    assert hresult_name(0x84204053) == "J3 speed limit"
    assert hresult_name(0x84204048) == "J8 acceleration limit"
    assert hresult_name(0x8ABC1234) == "0x8ABC1234"
    assert hresult_name(-0x7EAFEFFD) == "motor off"  # the same code as a signed i32
    assert hresult_name(0) == "S_OK" and hresult_name(0x900) == "S_EXECUTING"


def test_function_names_come_from_fn() -> None:
    assert function_name(Fn.ROBOT_MOVE) == "Robot_Move" == Fn.ROBOT_MOVE.wire_name
    assert function_name(9) == "Controller_GetVariable"
    assert function_name(99) == "function 99"
    assert Fn(72) is Fn.ROBOT_MOVE and int(Fn.ROBOT_MOVE) == 72


def test_frame_serial_reads_a_framed_packet() -> None:
    assert frame_serial(encode_packet(0x1234, Fn.SERVICE_STOP)) == 0x1234


# --- decoder caps (hostile sizes) -------------------------------------------------------------

def _raw_packet(argc: int, body: bytes, serial: int = 1, code: int = 64) -> bytes:
    """A packet with a hand-set argument count (encode_packet refuses what we need here)."""
    total = 15 + len(body) + 1
    return struct.pack("<BIHHIH", 1, total, serial, 0, code, argc) + body + b"\x04"


def _arg(v: bytes) -> bytes:
    return struct.pack("<I", len(v)) + v


def test_ten_thousand_argument_packet_decodes() -> None:
    args = [Variant(VT_I4, i) if i % 2 else Variant(VT_R8, i / 4) for i in range(10_000)]
    p = decode_packet(encode_packet(7, Fn.ROBOT_EXECUTE, args))
    assert p.serial == 7 and list(p.args) == args


def test_argument_count_cap() -> None:
    body = _arg(encode_variant(Variant(VT_I4, 3))) * (MAX_ARGUMENTS + 1)
    with pytest.raises(ProtocolError, match=f"{MAX_ARGUMENTS + 1} arguments \\(max "):
        decode_packet(_raw_packet(MAX_ARGUMENTS + 1, body))
    assert len(decode_packet(_raw_packet(MAX_ARGUMENTS, body[:-14])).args) == MAX_ARGUMENTS


def test_packet_size_cap() -> None:
    big = _raw_packet(1, _arg(struct.pack("<HI", VT_UI1 | VT_ARRAY, MAX_PACKET_SIZE - 26)
                              + bytes(MAX_PACKET_SIZE - 26)))
    assert len(big) == MAX_PACKET_SIZE
    assert len(decode_packet(big).args[0].value) == MAX_PACKET_SIZE - 26
    bigger = _raw_packet(1, _arg(struct.pack("<HI", VT_UI1 | VT_ARRAY, MAX_PACKET_SIZE - 25)
                                 + bytes(MAX_PACKET_SIZE - 25)))
    with pytest.raises(ProtocolError, match="exceeds the 16777216-byte limit"):
        decode_packet(bigger)
    f = PacketFramer()
    f.feed(bigger[:64])
    with pytest.raises(ProtocolError, match="length field"):
        f.next_frame()


def test_typed_array_element_cap() -> None:
    n = MAX_ARRAY_ELEMENTS + 1
    with pytest.raises(ProtocolError, match=f"UI2\\|ARRAY of {n} elements \\(max"):
        decode_variant(struct.pack("<HI", VT_UI2 | VT_ARRAY, n) + bytes(2 * n))
    n = MAX_ARRAY_ELEMENTS
    v, end = decode_variant(struct.pack("<HI", VT_UI2 | VT_ARRAY, n) + bytes(2 * n))
    assert len(v.value) == n and end == 6 + 2 * n


def test_variant_count_cap() -> None:
    n = MAX_VARIANTS + 1
    empty = encode_variant(Variant(VT_EMPTY))
    data = struct.pack("<HI", VT_VARIANT | VT_ARRAY, n) + empty * n
    with pytest.raises(ProtocolError, match=f"more than {MAX_VARIANTS} VARIANTs"):
        decode_variant(data)
    with pytest.raises(ProtocolError, match=f"more than {MAX_VARIANTS} VARIANTs"):
        decode_packet(_raw_packet(1, _arg(data)))
    # the budget is per packet: many arguments of arrays add up
    half = struct.pack("<HI", VT_VARIANT | VT_ARRAY, MAX_VARIANTS // 2) \
        + empty * (MAX_VARIANTS // 2)
    with pytest.raises(ProtocolError, match="VARIANTs in one packet"):
        decode_packet(_raw_packet(2, _arg(half) * 2))


def test_nesting_cap() -> None:
    v = Variant(VT_I4, 1)
    for _ in range(MAX_NESTING):
        v = Variant(VT_VARIANT | VT_ARRAY, [v])
    assert decode_variant(encode_variant(v))[0] == v
    deeper = encode_variant(Variant(VT_VARIANT | VT_ARRAY, [v]))
    with pytest.raises(ProtocolError, match=f"nesting deeper than {MAX_NESTING}"):
        decode_variant(deeper)
    with pytest.raises(ProtocolError, match="nesting deeper"):
        decode_packet(_raw_packet(1, _arg(deeper)))
