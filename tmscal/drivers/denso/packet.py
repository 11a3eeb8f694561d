"""b-CAP packets: wire constants, the function IDs (:class:`Fn`), packet encode/decode and
the stream framer.

Wire format (little-endian; DENSO WAVE's b-CAP communication specification)::

    SOH 0x01 | u32 total length (SOH..EOT) | u16 serial | u16 reserved |
    i32 function ID (request) or HRESULT (reply) | u16 argument count |
    per argument: u32 byte length, VARIANT | EOT 0x04

The VARIANTs are ``variant.py``'s, the HRESULTs ``hresult.py``'s.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from ...errors import ProtocolError
from .hresult import invalid_packet as _bad
from .hresult import is_failure
from .variant import Variant, VariantReader, encode_variant, to_variant

SOH = 0x01
EOT = 0x04
#: Bytes before the first argument: SOH, length, serial, reserved, code, argument count.
HEADER_SIZE = 15
#: The smallest packet: a header and EOT.
MIN_PACKET_SIZE = 16
_HEADER = "<BIHHIH"
# Packet caps. b-CAP itself only bounds a packet by its u32 length field and the argument
# count by u16; these keep a hostile or corrupt peer from making the decoder spend unbounded
# time or memory (requests carry at most 4 arguments). Exceeding one raises ProtocolError.
#: Largest packet the framer and ``decode_packet`` accept (bytes, 16 MiB).
MAX_PACKET_SIZE = 16 * 1024 * 1024
#: Most arguments one packet may carry (the wire field allows 65,535).
MAX_ARGUMENTS = 16384


class Fn(IntEnum):
    """b-CAP function IDs used by tmscal; ``wire_name`` is the specification's name
    (``Fn.ROBOT_MOVE.wire_name == "Robot_Move"``)."""

    wire_name: str

    def __new__(cls, fid: int, wire_name: str) -> Fn:
        member = int.__new__(cls, fid)
        member._value_ = fid
        member.wire_name = wire_name
        return member

    SERVICE_START = 1, "Service_Start"
    SERVICE_STOP = 2, "Service_Stop"
    CONTROLLER_CONNECT = 3, "Controller_Connect"
    CONTROLLER_DISCONNECT = 4, "Controller_Disconnect"
    CONTROLLER_GETROBOT = 7, "Controller_GetRobot"
    CONTROLLER_GETVARIABLE = 9, "Controller_GetVariable"
    CONTROLLER_GETROBOTNAMES = 13, "Controller_GetRobotNames"
    CONTROLLER_EXECUTE = 17, "Controller_Execute"
    ROBOT_GETVARIABLE = 62, "Robot_GetVariable"
    ROBOT_EXECUTE = 64, "Robot_Execute"
    ROBOT_HALT = 70, "Robot_Halt"
    ROBOT_MOVE = 72, "Robot_Move"
    ROBOT_SPEED = 74, "Robot_Speed"
    ROBOT_RELEASE = 84, "Robot_Release"
    VARIABLE_GETVALUE = 101, "Variable_GetValue"
    VARIABLE_PUTVALUE = 102, "Variable_PutValue"
    VARIABLE_RELEASE = 111, "Variable_Release"


#: Specification name of every function ID in :class:`Fn`.
FUNCTION_NAMES: dict[int, str] = {int(f): f.wire_name for f in Fn}


def function_name(fid: int) -> str:
    """Name of a b-CAP function ID, e.g. ``"Robot_Move"``; unknown IDs as ``"function 99"``."""
    return FUNCTION_NAMES.get(fid, f"function {fid}")


def frame_serial(frame: bytes) -> int:
    """The serial of a framed packet (from :meth:`PacketFramer.next_frame`), read before the
    packet is decoded, so that even a malformed request can be answered."""
    (serial,) = struct.unpack_from("<H", frame, 5)
    return int(serial)


def next_serial(serial: int) -> int:
    """The serial after ``serial``: +1, wrapping 0xFFFF → 1, never 0."""
    return 1 if serial >= 0xFFFF or serial < 1 else serial + 1


@dataclass(frozen=True)
class Packet:
    """One b-CAP packet. ``code`` is the function ID (request) or the HRESULT (reply), as an
    unsigned 32-bit int; ``args`` the VARIANT arguments / return values."""

    serial: int
    code: int
    args: tuple[Variant, ...] = ()
    reserved: int = 0

    @property
    def failed(self) -> bool:
        return is_failure(self.code)


def encode_packet(serial: int, code: int, args: Sequence[Any] = (), reserved: int = 0) -> bytes:
    """Wire bytes of a packet. ``args`` are Variants or Python values (via
    :func:`to_variant`); ``code`` a function ID or HRESULT (negative values allowed)."""
    if not 0 <= serial <= 0xFFFF:
        raise ValueError(f"serial {serial} outside 0..65535")
    if not -(1 << 31) <= code <= 0xFFFFFFFF:
        raise ValueError(f"code {code} does not fit in 32 bits")
    if len(args) > 0xFFFF:
        raise ValueError(f"{len(args)} arguments (max 65535)")
    body = bytearray()
    for a in args:
        vb = encode_variant(to_variant(a))
        body += struct.pack("<I", len(vb)) + vb
    total = HEADER_SIZE + len(body) + 1
    head = struct.pack(_HEADER, SOH, total, serial, reserved & 0xFFFF,
                       code & 0xFFFFFFFF, len(args))
    return head + bytes(body) + bytes([EOT])


def decode_packet(data: bytes) -> Packet:
    """Decode exactly one complete packet. Raises ``ProtocolError`` (code E_INVALIDPACKET)
    naming the fault: wrong SOH or EOT, a length field that disagrees with the bytes,
    truncated arguments, an argument length that disagrees with its VARIANT, trailing bytes
    before EOT, or a packet beyond the decoder's caps (:data:`MAX_PACKET_SIZE`,
    :data:`MAX_ARGUMENTS`, :data:`MAX_ARRAY_ELEMENTS`, :data:`MAX_VARIANTS`,
    :data:`MAX_NESTING`). Time and memory are linear in the packet size."""
    if len(data) > MAX_PACKET_SIZE:
        raise _bad(f"packet of {len(data)} bytes exceeds the {MAX_PACKET_SIZE}-byte limit")
    data = bytes(data)
    if len(data) < MIN_PACKET_SIZE:
        raise _bad(f"truncated packet: {len(data)} bytes, a packet has at least "
                   f"{MIN_PACKET_SIZE}")
    if data[0] != SOH:
        raise _bad(f"wrong SOH 0x{data[0]:02X} (expected 0x01)")
    soh, total, serial, reserved, code, argc = struct.unpack_from(_HEADER, data, 0)
    if total != len(data):
        raise _bad(f"length field {total} disagrees with the {len(data)} bytes received")
    if data[-1] != EOT:
        raise _bad(f"wrong EOT 0x{data[-1]:02X} (expected 0x04)")
    if argc > MAX_ARGUMENTS:
        raise _bad(f"{argc} arguments (max {MAX_ARGUMENTS})")
    end = len(data) - 1
    reader = VariantReader(data, end)
    pos = HEADER_SIZE
    args = []
    for i in range(argc):
        if pos + 4 > end:
            raise _bad(f"truncated packet: argument {i + 1} of {argc} missing")
        (alen,) = struct.unpack_from("<I", data, pos)
        pos += 4
        if pos + alen > end:
            raise _bad(f"argument {i + 1} length {alen} runs past the packet end")
        reader.end = pos + alen  # the VARIANT must lie within its announced length
        try:
            v, vend = reader.variant(pos, 0)
        except ProtocolError as e:
            raise _bad(f"argument {i + 1} of {argc} (length {alen}): "
                       f"{e.args[0].removeprefix('b-CAP: ')}") from None
        if vend != pos + alen:
            raise _bad(f"argument {i + 1} length {alen} disagrees with its VARIANT "
                       f"({vend - pos} bytes)")
        args.append(v)
        pos = vend
    if pos != end:
        raise _bad(f"{end - pos} unexpected bytes after {argc} arguments")
    return Packet(serial=serial, code=code, args=tuple(args), reserved=reserved)


@dataclass
class PacketFramer:
    """Frames b-CAP packets out of a TCP byte stream.

    ``feed(data)`` appends bytes; ``next_frame()`` returns the next complete packet's bytes or
    None when more bytes are needed. Bad framing (wrong SOH, a length below 16 or above
    ``max_size``, wrong EOT at the announced end) raises ``ProtocolError`` after dropping the
    bad bytes up to the next SOH, so the caller can carry on; every error consumes at least
    one byte, so a loop over ``next_frame()`` always ends.
    """

    max_size: int = MAX_PACKET_SIZE
    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> None:
        self._buf += data

    @property
    def buffered(self) -> int:
        """Bytes held that do not yet form a packet."""
        return len(self._buf)

    def _resync(self) -> None:
        i = self._buf.find(bytes([SOH]), 1)
        del self._buf[:i if i > 0 else len(self._buf)]

    def next_frame(self) -> bytes | None:
        if not self._buf:
            return None
        if self._buf[0] != SOH:
            bad = self._buf[0]
            self._resync()
            raise _bad(f"wrong SOH 0x{bad:02X} (expected 0x01); resynchronising")
        if len(self._buf) < 5:
            return None
        (total,) = struct.unpack_from("<I", self._buf, 1)
        if total < MIN_PACKET_SIZE or total > self.max_size:
            self._resync()
            raise _bad(f"length field {total} outside {MIN_PACKET_SIZE}..{self.max_size}")
        if len(self._buf) < total:
            return None
        if self._buf[total - 1] != EOT:
            bad = self._buf[total - 1]
            self._resync()
            raise _bad(f"wrong EOT 0x{bad:02X} at offset {total - 1} (expected 0x04)")
        frame = bytes(self._buf[:total])
        del self._buf[:total]
        return frame

    def next_packet(self) -> Packet | None:
        """The next decoded packet, or None when more bytes are needed."""
        frame = self.next_frame()
        return None if frame is None else decode_packet(frame)

    def packets(self) -> Iterator[Packet]:
        """Every complete packet buffered so far (stops at the first ``ProtocolError``)."""
        while (p := self.next_packet()) is not None:
            yield p


__all__ = [
    "Packet", "PacketFramer", "Fn", "encode_packet", "decode_packet", "function_name",
    "next_serial", "frame_serial", "FUNCTION_NAMES", "MAX_PACKET_SIZE", "MAX_ARGUMENTS",
    "SOH", "EOT", "HEADER_SIZE", "MIN_PACKET_SIZE",
]
