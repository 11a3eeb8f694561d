"""OpenIGTLink on the wire: the 58-byte header, the version-2 body layout (extended header,
content, metadata), the CRC and TRANSFORM messages, for the driver and the mock alike, and the
STATUS message tmscal's stream server sends.

The OpenIGTLink specification (openigtlink.org, "OpenIGTLink Protocol", header versions 1
and 2) defines every message as a 58-byte big-endian header (header version uint16, type
char[12], device name char[20], timestamp uint64, body size uint64, CRC-64 of the body) and a
body. A version-2 body (OpenIGTLink 3) is a 12-byte extended header (its own size uint16,
metadata header size uint16, metadata size uint32, message id uint32), the content, a
metadata header (count uint16, then per entry key size uint16, value encoding uint16, value
size uint32) and the metadata keys and values. The timestamp is seconds (high 32 bits) and a
fraction of a second in units of 2⁻³² s (low 32 bits). A TRANSFORM's content is 12 float32:
the rotation column by column, then the translation.

pyigtl does the message work: its ``CRC64`` (the ECMA-182 polynomial OpenIGTLink uses) and
its ``TransformMessage`` pack and unpack TRANSFORM content; :func:`encode` packs any message
through pyigtl's ``MessageBase``. What pyigtl does not do is refuse a malformed message (it
unpacks without a CRC check, trusts every size field and raises whatever Python raises); the
checks here make every malformed input one :class:`~tmscal.errors.ProtocolError`.

Units: TRANSFORM translations are whatever the sender uses; PlusServer sends mm (PlusLib
works in mm throughout: docs/devices.md, "OpenIGTLink tracker (PlusServer)").
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pyigtl import MessageBase, TransformMessage
from pyigtl.messages import CRC64

from ...errors import ProtocolError

__all__ = ["STATUS_CODES", "StatusMessage", "HEADER_SIZE", "MAX_BODY_SIZE", "MAX_NAME_BYTES",
           "Header", "Transform",
           "parse_header", "split_body", "decode_transform", "encode", "encode_transform",
           "timestamp_parts"]

HEADER_SIZE = 58
#: the largest body the driver accepts (an IMAGE on the same stream can be megabytes);
#: a larger size field means the bytes are not an OpenIGTLink stream
MAX_BODY_SIZE = 64 << 20
#: device names are char[20] (PlusServer cuts longer transform names to their first 20)
MAX_NAME_BYTES = 20
_TYPE_BYTES = 12
_EXT_HEADER_SIZE = 12
_TRANSFORM_CONTENT = 48
_HEADER = struct.Struct(">H12s20sQQQ")
_EXT = struct.Struct(">HHII")
_ENTRY = struct.Struct(">HHI")
#: IANA character sets of metadata values (RFC 2978 registry numbers) the driver decodes
_ENCODINGS = {3: "ascii", 106: "utf-8", 4: "latin-1"}


@dataclass(frozen=True)
class Header:
    """A message header: ``version`` (1 or 2), ``type`` ("TRANSFORM", "STATUS" …),
    ``device`` name, ``stamp`` (the raw 64-bit timestamp: seconds << 32 | fraction),
    ``body_size`` (bytes) and ``crc`` (CRC-64 of the body)."""

    version: int
    type: str
    device: str
    stamp: int
    body_size: int
    crc: int

    @property
    def timestamp(self) -> float:
        """The timestamp in seconds (PlusServer: UTC, seconds since 1970)."""
        return (self.stamp >> 32) + (self.stamp & 0xFFFFFFFF) / 2.0**32


@dataclass(frozen=True)
class Transform:
    """A decoded TRANSFORM: ``device`` name, raw ``stamp`` and ``timestamp`` (s), ``matrix``
    4×4 float64 (the sender's frame from the device's: PlusServer's ``MarkerToTracker`` is
    tracker_from_marker, mm), ``metadata`` (version-2 key → value, e.g. PlusServer's
    ``TransformStatus``), ``version`` (header version) and ``message_id``."""

    device: str
    stamp: int
    timestamp: float
    matrix: np.ndarray
    metadata: Mapping[str, str] = field(default_factory=dict)
    version: int = 1
    message_id: int = 0


def _name(raw: bytes, what: str, ascii_only: bool) -> str:
    """A NUL-padded char[] field as text (up to the first NUL)."""
    text = raw.split(b"\0", 1)[0]
    try:
        s = text.decode("ascii" if ascii_only else "utf-8")
    except UnicodeDecodeError:
        raise ProtocolError(f"OpenIGTLink header: {what} {text!r} is not "
                            f"{'ASCII' if ascii_only else 'UTF-8'} text") from None
    if ascii_only and (not s or not s.isprintable() or " " in s):
        raise ProtocolError(f"OpenIGTLink header: {what} {text!r} is not a message type "
                            "(printable ASCII without spaces)")
    return s


def parse_header(data: bytes) -> Header:
    """The header of ``data`` (exactly :data:`HEADER_SIZE` bytes). ``ProtocolError`` for a
    header version other than 1 or 2, a type that is not printable ASCII, a device name that
    is not UTF-8 or a body size over :data:`MAX_BODY_SIZE`."""
    if len(data) != HEADER_SIZE:
        raise ProtocolError(f"OpenIGTLink header: {len(data)} bytes, expected {HEADER_SIZE}")
    version, mtype, device, stamp, size, crc = _HEADER.unpack(data)
    if version not in (1, 2):
        raise ProtocolError(f"OpenIGTLink header: header version {version} (expected 1 or 2; "
                            f"first bytes {bytes(data[:16])!r}): not an OpenIGTLink stream?")
    t = _name(mtype, "type", ascii_only=True)
    d = _name(device, "device name", ascii_only=False)
    if size > MAX_BODY_SIZE:
        raise ProtocolError(f"OpenIGTLink {t} {d!r}: body of {size} bytes (more than "
                            f"{MAX_BODY_SIZE >> 20} MiB): not an OpenIGTLink stream?")
    return Header(version, t, d, stamp, size, crc)


def split_body(header: Header, body: bytes) -> tuple[bytes, dict[str, str], int]:
    """(content, metadata, message id) of ``body``, its CRC checked. A version-1 body is all
    content. ``ProtocolError`` for a CRC mismatch and for a version-2 layout whose sizes do
    not add up."""
    what = f"OpenIGTLink {header.type} {header.device!r}"
    if len(body) != header.body_size:
        raise ProtocolError(f"{what}: body of {len(body)} bytes, header says "
                            f"{header.body_size}")
    crc = CRC64(body)
    if crc != header.crc:
        raise ProtocolError(f"{what}: CRC mismatch (header {header.crc:016X}, body "
                            f"{crc:016X}): corrupted message")
    if header.version == 1:
        return body, {}, 0
    if len(body) < _EXT_HEADER_SIZE:
        raise ProtocolError(f"{what}: version-2 body of {len(body)} bytes has no extended "
                            "header")
    ext_size, meta_header, meta_size, message_id = _EXT.unpack_from(body)
    if ext_size < _EXT_HEADER_SIZE or ext_size + meta_header + meta_size > len(body):
        raise ProtocolError(f"{what}: extended header sizes {ext_size} + {meta_header} + "
                            f"{meta_size} do not fit a body of {len(body)} bytes")
    end = len(body) - meta_header - meta_size
    meta = _metadata(body[end:], meta_header, what)
    return body[ext_size:end], meta, message_id


def _metadata(data: bytes, header_size: int, what: str) -> dict[str, str]:
    """The metadata section (header then keys and values) as key → value text."""
    if header_size == 0 and not data:
        return {}
    if header_size < 2:
        raise ProtocolError(f"{what}: metadata header of {header_size} bytes has no count")
    (count,) = struct.unpack_from(">H", data)
    if header_size != 2 + count * _ENTRY.size:
        raise ProtocolError(f"{what}: metadata header of {header_size} bytes for {count} "
                            "entries (expected 2 + 8 per entry)")
    entries = [_ENTRY.unpack_from(data, 2 + i * _ENTRY.size) for i in range(count)]
    pos = header_size
    if sum(k + v for k, _, v in entries) != len(data) - header_size:
        raise ProtocolError(f"{what}: metadata entries do not add up to the "
                            f"{len(data) - header_size} bytes of keys and values")
    out: dict[str, str] = {}
    for key_size, encoding, value_size in entries:
        key = data[pos:pos + key_size].decode("utf-8", "replace")
        value = data[pos + key_size:pos + key_size + value_size]
        out[key] = value.decode(_ENCODINGS.get(encoding, "latin-1"), "replace")
        pos += key_size + value_size
    return out


def decode_transform(header: Header, body: bytes) -> Transform:
    """The TRANSFORM of ``header`` and ``body`` (CRC and layout checked by
    :func:`split_body`; the 48 content bytes unpacked by pyigtl's ``TransformMessage``).
    ``ProtocolError`` when the content is not 48 bytes."""
    if header.type != "TRANSFORM":
        raise ProtocolError(f"OpenIGTLink {header.type} {header.device!r} is not a TRANSFORM")
    content, meta, message_id = split_body(header, body)
    if len(content) != _TRANSFORM_CONTENT:
        raise ProtocolError(f"OpenIGTLink TRANSFORM {header.device!r}: content of "
                            f"{len(content)} bytes, expected {_TRANSFORM_CONTENT}")
    msg = TransformMessage()
    msg.unpack({"header_version": 1, "message_type": header.type,
                "device_name": header.device, "timestamp": header.timestamp,
                "body_size": len(content)}, content)
    return Transform(header.device, header.stamp, header.timestamp,
                     np.array(msg.matrix, dtype=np.float64), meta, header.version, message_id)


def timestamp_parts(seconds: float) -> tuple[int, int]:
    """(seconds, fraction in units of 2⁻³² s) of a timestamp in seconds."""
    whole = math.floor(seconds)
    frac = min(int(round((seconds - whole) * 2.0**32)), 0xFFFFFFFF)
    return whole & 0xFFFFFFFF, frac


class _Message(MessageBase):
    """Any OpenIGTLink message as pyigtl packs it: a type, a device name and fixed content
    bytes (pyigtl has classes for TRANSFORM, IMAGE, STRING, POINT, POSITION only)."""

    def __init__(self, mtype: str, device: str, content: bytes, timestamp: float) -> None:
        super().__init__(timestamp=timestamp, device_name=device)
        self._message_type = mtype
        self._content = content
        self._valid_message = True

    def _pack_content(self) -> bytes:
        return self._content


#: OpenIGTLink STATUS codes (openigtlink.org, "STATUS" message, protocol version 2) used here
STATUS_CODES = {"ok": 1, "error": 2, "not_found": 4, "not_present": 16, "exiting": 19}


class StatusMessage(MessageBase):
    """An OpenIGTLink STATUS message (pyigtl 0.3 has none): the content is the status
    ``code`` (uint16, :data:`STATUS_CODES`), a ``subcode`` (int64, device-specific), an
    ``error_name`` (char[20], zero-padded) and a ``status_string`` (UTF-8, zero-terminated),
    all big-endian, as the specification defines it (the live monitor's alarms, sent by
    ``tmscal.stream.StreamServer.send_status``)."""

    def __init__(self, code: int = 1, subcode: int = 0, error_name: str = "",
                 status_string: str = "", timestamp: float | None = None,
                 device_name: str | None = None) -> None:
        super().__init__(timestamp=timestamp, device_name=device_name)
        self._message_type = "STATUS"
        self.code, self.subcode = int(code), int(subcode)
        self.error_name, self.status_string = error_name, status_string
        self._valid_message = True

    def _pack_content(self) -> bytes:
        name = self.error_name.encode("utf-8")[:20]
        return (struct.pack(">Hq20s", self.code, self.subcode, name)
                + self.status_string.encode("utf-8") + b"\0")

    def _unpack_content(self, content: bytes) -> None:
        self.code, self.subcode, name = struct.unpack_from(">Hq20s", content)
        self.error_name = name.rstrip(b"\0").decode("utf-8", "replace")
        self.status_string = content[30:].split(b"\0", 1)[0].decode("utf-8", "replace")


def _pack(msg: MessageBase, stamp: int | None, version: int,
          metadata: Mapping[str, str] | None) -> bytes:
    """``msg`` packed by pyigtl with header ``version`` and ``metadata`` (version 2 only),
    the timestamp field then set to the raw ``stamp`` (pyigtl rounds through a float) and
    the CRC left as pyigtl computed it (the timestamp is not covered by it)."""
    msg.header_version = version
    msg.metadata = dict(metadata or {}) if version > 1 else {}
    data = msg.pack()
    if stamp is not None:
        data = data[:34] + struct.pack(">Q", stamp) + data[42:]
    return data


def encode(mtype: str, device: str = "", content: bytes = b"", *, stamp: int = 0,
           version: int = 1, metadata: Mapping[str, str] | None = None) -> bytes:
    """A message of type ``mtype`` with raw ``content`` (e.g. ``GET_STATUS`` with none,
    PlusServer's keep-alive ``STATUS``), packed through pyigtl."""
    return _pack(_Message(mtype, device, content, 0.0), stamp, version, metadata)


def encode_transform(device: str, matrix: Any, *, stamp: int, version: int = 1,
                     metadata: Mapping[str, str] | None = None) -> bytes:
    """A TRANSFORM of ``matrix`` (4×4; sent as float32, as the protocol has it) named
    ``device`` with the raw timestamp ``stamp``, packed by pyigtl's ``TransformMessage``."""
    return _pack(TransformMessage(np.asarray(matrix, dtype=np.float64), device_name=device),
                 stamp, version, metadata)
