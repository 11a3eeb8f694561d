"""Property tests: random and mutated byte streams into every NDI parser raise only
ProtocolError (``raise_for_error`` alone raises a plain DeviceError, for an ERRORxx reply),
never anything else, and return quickly. Budgets: ``tests.fuzz.fuzz_settings``."""

from __future__ import annotations

import struct

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.drivers.ndi import protocol as p
from tmscal.errors import DeviceError, ProtocolError

SETTINGS = fuzz_settings(200)


def _valid_replies() -> list[bytes]:
    rec = p.HandleRecord.valid(1, (0.7071, 0, 0, 0.7071), (10.5, -20.25, -1500.0), 0.12, 0x31,
                               10)
    miss = p.HandleRecord.missing_tool(2, 0x71, 10)
    return [
        p.frame_reply("OKAY"), p.frame_reply("ERROR0C"), p.frame_reply("WARNING02"),
        p.frame_reply("RESET"), p.frame_reply(p.encode_tx([rec, miss], 2)),
        p.frame_reply(p.encode_phsr({1: 0x31, 2: 0x01})), p.frame_reply("0A"),
        p.encode_bx([rec, miss], 2),
    ]


VALID = _valid_replies()


@st.composite
def mutated(draw: st.DrawFn) -> bytes:
    data = bytearray(draw(st.sampled_from(VALID)))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "delete", "insert", "truncate"]))
        if not data:
            break
        i = draw(st.integers(0, len(data) - 1))
        if op == "flip":
            data[i] ^= draw(st.integers(1, 255))
        elif op == "delete":
            del data[i]
        elif op == "insert":
            data.insert(i, draw(st.integers(0, 255)))
        else:
            del data[i:]
    return bytes(data)


def _all_parsers(data: bytes) -> None:
    """Feed ``data`` to every parser; only ProtocolError may escape (anything else, another
    DeviceError subclass included, fails the test)."""
    for fn in (p.parse_reply, p.decode_bx, p.reply_length, p.parse_command, p.check_bx,
               p.split_reply):
        try:
            fn(data)
        except ProtocolError:
            pass
    text = data.decode("latin-1")
    for fn2 in (p.decode_tx, p.decode_phsr, p.decode_phrq, p.classify_reply, p.parse_ver):
        try:
            fn2(text)
        except ProtocolError:
            pass
    try:
        reply = p.parse_reply(data)
    except ProtocolError:
        return
    try:
        p.raise_for_error(reply, "X")
    except DeviceError as e:  # an ERRORxx reply: exactly DeviceError, with its code
        assert type(e) is DeviceError and reply.kind == "error" and e.code == reply.code


@SETTINGS
@given(st.binary(max_size=300))
def test_random_bytes_raise_only_protocol_errors(data: bytes) -> None:
    _all_parsers(data)


@SETTINGS
@given(mutated())
def test_mutated_replies_raise_only_protocol_errors(data: bytes) -> None:
    _all_parsers(data)


@SETTINGS
@given(st.text(alphabet="0123456789ABCDEF+-MISNGDABLE\n", max_size=200))
def test_tx_like_text_raises_only_protocol_errors(text: str) -> None:
    try:
        p.decode_tx(text)
    except ProtocolError:
        pass


@SETTINGS
@given(st.lists(st.tuples(st.integers(0, 255), st.sampled_from([1, 2, 4]),
                          st.lists(st.floats(width=32, allow_nan=True), min_size=8,
                                   max_size=8)), max_size=5),
       st.integers(0, 0xFFFF))
def test_bx_with_valid_crcs_and_any_floats(items, sys_status: int) -> None:
    """Well-framed BX bodies with arbitrary floats (NaN, inf, zero quaternions) decode or
    raise ProtocolError; valid finite ones give rigid poses."""
    body = bytearray([len(items)])
    for h, status, vals in items:
        body += bytes([h, status])
        if status == 1:
            body += struct.pack("<8f", *vals) + struct.pack("<II", 0x31, 1)
        elif status == 2:
            body += struct.pack("<II", 0x31, 1)
    body += struct.pack("<H", sys_status)
    head = struct.pack("<HH", 0xA5C4, len(body))
    raw = head + struct.pack("<H", p.crc16(head)) + bytes(body) + struct.pack("<H",
                                                                              p.crc16(body))
    try:
        bx = p.decode_bx(raw)
    except ProtocolError:
        return
    assert bx.system_status == sys_status
    for r in bx.records:
        if r.pose is not None:
            R = r.pose[:3, :3]
            np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-6)


@SETTINGS
@given(st.binary(max_size=200))
def test_reply_length_never_overshoots_text(data: bytes) -> None:
    try:
        n = p.reply_length(data)
    except ProtocolError:
        return
    if n is not None and data[:1] != b"\xc4":
        assert data[n - 1:n] == b"\r" and b"\r" not in data[:n - 1]


# --- tracker.port: a network address must say socket:// ----------------------------------------

_IPV4 = st.tuples(*[st.integers(0, 255)] * 4).map(lambda t: ".".join(map(str, t)))
_NAME = st.from_regex(r"[A-Za-z0-9][A-Za-z0-9.-]{0,30}", fullmatch=True)


@SETTINGS
@given(host=st.one_of(_IPV4, _NAME), port=st.integers(1, 65535))
def test_a_bare_host_and_port_is_refused_with_its_socket_url(host: str, port: int) -> None:
    from tmscal.drivers.ndi.settings import tracker_port_problem

    problem = tracker_port_problem(f"{host}:{port}")
    assert problem is not None and f"socket://{host}:{port}" in problem
    assert tracker_port_problem(f"socket://{host}:{port}") is None


@SETTINGS
@given(st.text(max_size=80))
def test_the_port_check_answers_every_text_and_passes_device_paths(text: str) -> None:
    """Any text gets None or a reason, never an exception; a path under /dev without a URL
    scheme or a control character is a device path, whatever colons it holds."""
    from tmscal.drivers.ndi.settings import tracker_port_problem

    assert tracker_port_problem(text) is None or isinstance(tracker_port_problem(text), str)
    path = "/dev/" + text
    if "://" not in path and not any(c in path for c in "\0\r\n"):
        assert tracker_port_problem(path) is None
