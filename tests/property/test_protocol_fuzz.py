"""Structure-aware fuzzing of the device-protocol decoders: inputs that pass the outer checks
(valid framing, valid CRCs, plausible headers) so the inner parsers are exercised.

Only ``ProtocolError`` may escape a decoder: any other exception, another ``DeviceError``
subclass included, fails the test. CI runs a small budget; ``pytest --fuzz-long`` runs at
least 100,000 examples per test (``tests.fuzz``).
"""

from __future__ import annotations

import math
import struct

from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tests.property.test_bcap_parsers import variants
from tmscal.drivers.denso import variant as b
from tmscal.drivers.denso.client import finite_numbers
from tmscal.drivers.denso.packet import (
    Packet,
    PacketFramer,
    decode_packet,
    encode_packet,
)
from tmscal.drivers.denso.variant import (
    Variant,
    decode_variant,
)
from tmscal.drivers.ndi import protocol as p
from tmscal.errors import ProtocolError

# --- b-CAP ------------------------------------------------------------------------------------

_VTS = sorted(b.VT_NAMES) + [9, 13, 14, 16, 22, 0x1FFF, 0xFFFF]
_vt = st.one_of(st.sampled_from(_VTS), st.sampled_from(_VTS).map(lambda v: v | b.VT_ARRAY),
                st.integers(0, 0xFFFF))
_count = st.one_of(st.integers(0, 8), st.sampled_from([0xFFFFFFFF, 1 << 20, (1 << 20) + 1,
                                                       1 << 31]))


@st.composite
def raw_variants(draw: st.DrawFn, depth: int = 0) -> bytes:
    """A VARIANT header (any type, small or huge count) and data that is sometimes valid:
    random bytes, or nested raw VARIANTs for VARIANT arrays."""
    vt, count = draw(_vt), draw(_count)
    head = struct.pack("<HI", vt, count)
    if vt == b.VT_VARIANT | b.VT_ARRAY and count <= 8 and depth < 3:
        return head + b"".join(draw(raw_variants(depth + 1)) for _ in range(count))
    if vt == b.VT_BSTR and draw(st.booleans()):
        text = draw(st.binary(max_size=12))
        return head + struct.pack("<I", len(text)) + text
    return head + draw(st.binary(max_size=40))


@st.composite
def raw_packets(draw: st.DrawFn) -> bytes:
    """A packet with a correct SOH, length field and EOT around arguments whose length fields
    are right, off by a little, or arbitrary; the argument count may disagree."""
    args = draw(st.lists(raw_variants(), max_size=5))
    body = b""
    for a in args:
        n = draw(st.sampled_from([len(a), len(a), len(a) - 1, len(a) + 1,
                                  draw(st.integers(0, 0xFFFFFFFF))]))
        body += struct.pack("<I", n & 0xFFFFFFFF) + a
    argc = draw(st.sampled_from([len(args), len(args), draw(st.integers(0, 0xFFFF))]))
    total = 15 + len(body) + 1
    return struct.pack("<BIHHIH", 1, total, draw(st.integers(0, 0xFFFF)), 0,
                       draw(st.integers(0, 0xFFFFFFFF)), argc) + body + b"\x04"


@fuzz_settings(300)
@given(raw_variants())
def test_fuzz_decode_variant_only_protocol_error(data: bytes) -> None:
    try:
        v, end = decode_variant(data)
    except ProtocolError:
        return
    assert isinstance(v, Variant) and 6 <= end <= len(data)


@fuzz_settings(300)
@given(raw_packets())
def test_fuzz_decode_packet_only_protocol_error(data: bytes) -> None:
    try:
        pkt = decode_packet(data)
    except ProtocolError:
        return
    assert isinstance(pkt, Packet) and all(isinstance(a, Variant) for a in pkt.args)
    (argc,) = struct.unpack_from("<H", data, 13)
    assert len(pkt.args) == argc


@st.composite
def chunked_streams(draw: st.DrawFn) -> tuple[list[Packet], list[bytes]]:
    """Valid packets, concatenated and cut at arbitrary points."""
    pkts = [Packet(draw(st.integers(0, 0xFFFF)), draw(st.integers(0, 0xFFFFFFFF)),
                   tuple(draw(st.lists(variants, max_size=2))))
            for _ in range(draw(st.integers(1, 4)))]
    stream = b"".join(encode_packet(q.serial, q.code, q.args) for q in pkts)
    cuts = sorted(draw(st.lists(st.integers(0, len(stream)), max_size=6)))
    edges = [0, *cuts, len(stream)]
    return pkts, [stream[i:j] for i, j in zip(edges, edges[1:], strict=False)]


@fuzz_settings(150)
@given(chunked_streams())
def test_fuzz_framer_reassembles_any_split(case: tuple[list[Packet], list[bytes]]) -> None:
    pkts, chunks = case
    f = PacketFramer()
    got = []
    for c in chunks:
        f.feed(c)
        got.extend(f.packets())
    assert got == pkts and f.buffered == 0


@fuzz_settings(150)
@given(st.lists(st.one_of(st.binary(max_size=30), raw_packets()), max_size=6))
def test_fuzz_framer_on_garbage_and_packets_terminates(parts: list[bytes]) -> None:
    data = b"".join(parts)
    f = PacketFramer(max_size=1 << 16)
    f.feed(data)
    for _ in range(len(data) + 2):  # every step consumes ≥ 1 byte or stops
        try:
            if f.next_packet() is None:
                break
        except ProtocolError:
            continue
    else:
        raise AssertionError("framer did not settle")


_any_float = st.floats(allow_nan=True, allow_infinity=True)
_number_variants = st.one_of(
    st.lists(_any_float, max_size=9).map(lambda xs: Variant(b.VT_R8 | b.VT_ARRAY, xs)),
    st.lists(st.floats(width=32), max_size=9).map(lambda xs: Variant(b.VT_R4 | b.VT_ARRAY, xs)),
    st.lists(st.integers(-(1 << 31), (1 << 31) - 1), max_size=9).map(
        lambda xs: Variant(b.VT_I4 | b.VT_ARRAY, xs)),
    st.lists(st.one_of(_any_float.map(lambda x: Variant(b.VT_R8, x)),
                       st.integers(-9, 9).map(lambda x: Variant(b.VT_I2, x)),
                       st.just(Variant(b.VT_BSTR, "1")), st.just(Variant(b.VT_BOOL, True))),
             max_size=9).map(lambda xs: Variant(b.VT_VARIANT | b.VT_ARRAY, xs)),
    variants,
)


@fuzz_settings(300)
@given(_number_variants)
def test_fuzz_curpos_reply_check(v: Variant) -> None:
    """Whatever a controller answers to CurPos, the client returns 6–7 finite floats or raises
    ProtocolError naming CurPos."""
    try:
        vals = finite_numbers(v, "Robot_Execute CurPos", 6, 7)
    except ProtocolError as e:
        assert "CurPos" in str(e)
        return
    assert 6 <= len(vals) <= 7 and all(isinstance(x, float) and math.isfinite(x)
                                       for x in vals)


# --- NDI Combined API -------------------------------------------------------------------------

@fuzz_settings(300)
@given(st.binary(max_size=200), st.binary(max_size=50))
def test_fuzz_crc16_properties(a: bytes, c: bytes) -> None:
    """CRC-16/ARC: appending the CRC (little-endian) gives a zero remainder, and the running
    form equals the one-shot form."""
    crc = p.crc16(a)
    assert 0 <= crc <= 0xFFFF
    assert p.crc16(a + struct.pack("<H", crc)) == 0
    assert p.crc16(c, p.crc16(a)) == p.crc16(a + c)


_tx_text = st.text(alphabet="0123456789ABCDEFabcdef+-MISNGDABLE \n", max_size=120)


@fuzz_settings(300)
@given(st.one_of(_tx_text, st.text(max_size=60)))
def test_fuzz_framed_text_replies_only_protocol_error(payload: str) -> None:
    """Any payload with a correct CRC: every text parser decodes it or raises ProtocolError."""
    data = payload.encode("utf-8", "surrogatepass")
    raw = data + b"%04X\r" % p.crc16(data)
    try:
        reply = p.parse_reply(raw)
    except ProtocolError:
        return
    assert reply.kind in ("okay", "error", "warning", "reset", "data")
    for fn in (p.decode_tx, p.decode_phsr, p.decode_phrq):
        try:
            fn(reply.text)
        except ProtocolError:
            pass
    assert isinstance(p.parse_ver(reply.text), dict)


@st.composite
def tx_payloads(draw: st.DrawFn) -> str:
    """TX payloads built from plausible rows (valid, MISSING, DISABLED, damaged)."""
    def signed(d: int) -> str:
        return draw(st.sampled_from("+-")) + "".join(
            draw(st.sampled_from("0123456789")) for _ in range(d))

    def hx(n: int) -> str:
        return "".join(draw(st.sampled_from("0123456789ABCDEF")) for _ in range(n))

    rows = []
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(["valid", "missing", "disabled", "junk"]))
        if kind == "valid":
            body = "".join(signed(5) for _ in range(4)) + "".join(signed(6) for _ in range(3))
            body += signed(5) + hx(8) + hx(8)
        elif kind == "missing":
            body = "MISSING" + hx(8) + hx(8)
        elif kind == "disabled":
            body = "DISABLED" + draw(st.sampled_from(["", hx(8) + hx(8)]))
        else:
            body = draw(_tx_text)
        rows.append(hx(2) + body)
    count = draw(st.sampled_from([len(rows), len(rows), draw(st.integers(0, 255))]))
    return f"{count:02X}" + "".join(r + "\n" for r in rows) + draw(
        st.sampled_from([hx(4), hx(3), hx(5), ""]))


@fuzz_settings(300)
@given(tx_payloads())
def test_fuzz_decode_tx_only_protocol_error(payload: str) -> None:
    try:
        tx = p.decode_tx(payload)
    except ProtocolError:
        return
    for r in tx.records:
        if r.pose is not None:
            assert r.pose.shape == (4, 4) and bool(abs(r.pose).max() < math.inf)


@st.composite
def bx_replies(draw: st.DrawFn) -> bytes:
    """BX replies with correct start sequence and both CRCs around a body that is built from
    plausible records or is arbitrary bytes."""
    if draw(st.booleans()):
        body = draw(st.binary(max_size=120))
    else:
        recs = b""
        n = draw(st.integers(0, 4))
        for _ in range(n):
            status = draw(st.sampled_from([1, 2, 4, draw(st.integers(0, 255))]))
            recs += bytes([draw(st.integers(0, 255)), status])
            if status == 1:
                recs += draw(st.binary(min_size=32, max_size=32)) + draw(st.binary(min_size=8,
                                                                               max_size=8))
            elif status == 2:
                recs += draw(st.binary(min_size=8, max_size=8))
        count = draw(st.sampled_from([n, n, draw(st.integers(0, 255))]))
        body = bytes([count]) + recs + draw(st.binary(min_size=0, max_size=3))
    head = struct.pack("<HH", 0xA5C4, len(body))
    return head + struct.pack("<H", p.crc16(head)) + body + struct.pack("<H", p.crc16(body))


@fuzz_settings(300)
@given(bx_replies())
def test_fuzz_decode_bx_only_protocol_error(raw: bytes) -> None:
    assert p.reply_length(raw) == len(raw)
    try:
        bx = p.decode_bx(raw)
    except ProtocolError:
        return
    for r in bx.records:
        if r.pose is not None:
            assert r.pose.shape == (4, 4) and bool(abs(r.pose).max() < math.inf)
