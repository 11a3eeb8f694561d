"""Property tests for the b-CAP parsers: random and damaged bytes raise only ProtocolError
(never hang), and random VARIANTs / packets survive an encode/decode round trip."""

from __future__ import annotations

from decimal import Decimal

from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.drivers.denso import variant as b
from tmscal.drivers.denso.packet import (
    PacketFramer,
    decode_packet,
    encode_packet,
)
from tmscal.drivers.denso.variant import (
    Variant,
    decode_variant,
    encode_variant,
)
from tmscal.errors import ProtocolError

SETTINGS = fuzz_settings(200)

_ints = {vt: st.integers(lo, hi) for vt, (lo, hi) in b._INT_RANGES.items()}
_elem = {
    **_ints,
    b.VT_R4: st.floats(width=32, allow_nan=False),
    b.VT_R8: st.floats(allow_nan=False),
    b.VT_DATE: st.floats(allow_nan=False, allow_infinity=False),
    b.VT_CY: st.integers(-(1 << 63), (1 << 63) - 1).map(lambda i: Decimal(i).scaleb(-4)),
    b.VT_BSTR: st.text(max_size=20),
    b.VT_BOOL: st.booleans(),
}


def _scalar() -> st.SearchStrategy[Variant]:
    return st.one_of(
        st.sampled_from([Variant(b.VT_EMPTY), Variant(b.VT_NULL)]),
        *[s.map(lambda x, vt=vt: Variant(vt, x)) for vt, s in _elem.items()],
    )


def _arrays() -> st.SearchStrategy[Variant]:
    typed = [st.lists(s, max_size=8).map(lambda xs, vt=vt: Variant(vt | b.VT_ARRAY, xs))
             for vt, s in _elem.items() if vt != b.VT_UI1]
    return st.one_of(*typed, st.binary(max_size=16).map(
        lambda x: Variant(b.VT_UI1 | b.VT_ARRAY, x)))


variants = st.recursive(
    st.one_of(_scalar(), _arrays()),
    lambda kids: st.one_of(
        st.lists(kids, max_size=4).map(lambda xs: Variant(b.VT_VARIANT | b.VT_ARRAY, xs)),
        kids.map(lambda v: Variant(b.VT_VARIANT, v)),
    ),
    max_leaves=12,
)


@SETTINGS
@given(variants)
def test_variant_round_trip(v: Variant) -> None:
    enc = encode_variant(v)
    back, end = decode_variant(enc)
    assert end == len(enc)
    assert back == v


@SETTINGS
@given(st.integers(0, 0xFFFF), st.integers(0, 0xFFFFFFFF), st.lists(variants, max_size=4))
def test_packet_round_trip(serial: int, code: int, args: list[Variant]) -> None:
    p = decode_packet(encode_packet(serial, code, args))
    assert (p.serial, p.code, list(p.args)) == (serial, code, args)


@SETTINGS
@given(st.binary(max_size=300))
def test_random_bytes_only_protocol_error(data: bytes) -> None:
    try:
        decode_packet(data)
    except ProtocolError:
        pass
    try:
        decode_variant(data)
    except ProtocolError:
        pass
    f = PacketFramer(max_size=4096)
    f.feed(data)
    for _ in range(len(data) + 2):  # each step consumes ≥ 1 byte or stops
        try:
            if f.next_packet() is None:
                break
        except ProtocolError:
            pass
    else:
        raise AssertionError("framer did not settle")


@st.composite
def damaged_packets(draw: st.DrawFn) -> bytes:
    good = bytearray(encode_packet(draw(st.integers(0, 0xFFFF)), draw(st.integers(0, 200)),
                                   draw(st.lists(variants, max_size=3))))
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "cut", "insert", "delete"]))
        i = draw(st.integers(0, max(len(good) - 1, 0)))
        if kind == "flip" and good:
            good[i] ^= draw(st.integers(1, 255))
        elif kind == "cut":
            del good[i:]
        elif kind == "insert":
            good[i:i] = draw(st.binary(min_size=1, max_size=8))
        elif good:
            del good[i]
    return bytes(good)


@SETTINGS
@given(damaged_packets())
def test_damaged_packets_only_protocol_error(data: bytes) -> None:
    try:
        decode_packet(data)
    except ProtocolError:
        pass
    f = PacketFramer(max_size=1 << 16)
    f.feed(data + encode_packet(1, 2))
    for _ in range(len(data) + 40):
        try:
            p = f.next_packet()
        except ProtocolError:
            continue
        if p is None:
            break
    else:
        raise AssertionError("framer did not settle")
