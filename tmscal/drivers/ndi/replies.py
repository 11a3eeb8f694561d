"""NDI Combined API replies: framing of every reply and the text replies.

A text reply is the payload + 4 hex CRC + ``\\r`` (:func:`frame_reply`, :func:`split_reply`,
:func:`parse_reply`); a binary BX reply starts ``C4 A5`` and carries its own length and
CRCs (decoded in :mod:`.tracking`). :func:`reply_length` finds where the first complete
reply in a byte buffer ends, whichever kind it is. Also here: the payloads of the handle
management replies (PHSR, PHRQ) and VER.
"""

from __future__ import annotations

import enum
import re
import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from ...errors import DeviceError, ProtocolError
from .codes import DEVICE, error_text, warning_text
from .crc import crc16, crc_hex

__all__ = [
    "ReplyKind", "Reply", "frame_reply", "reply_length", "split_reply", "classify_reply",
    "parse_reply", "raise_for_error", "encode_error", "encode_warning", "OKAY_REPLY",
    "RESET_REPLY", "MAX_TEXT_REPLY", "BX_START", "BX_START_BYTES", "is_bx", "parse_hex",
    "encode_phsr", "decode_phsr", "decode_phrq", "parse_ver",
]

#: The BX start sequence as a little-endian uint16, and as it comes on the wire.
BX_START = 0xA5C4
BX_START_BYTES = struct.pack("<H", BX_START)
#: Longest text reply we accept before calling the stream garbage.
MAX_TEXT_REPLY = 65536

_HEX_RE = re.compile(r"[0-9A-Fa-f]+")
_ERR_RE = re.compile(r"(ERROR|WARNING)([0-9A-Fa-f]{2})")


def is_bx(raw: bytes | bytearray) -> bool:
    """Whether ``raw`` starts with the BX start sequence ``C4 A5``."""
    return raw[:2] == BX_START_BYTES


def parse_hex(s: str, what: str) -> int:
    """``s`` as a hex number; ``ProtocolError`` naming ``what`` if it is empty or not hex."""
    if not s or not _HEX_RE.fullmatch(s):
        raise ProtocolError(f"{what}: {s[:20]!r} is not hex", device=DEVICE)
    return int(s, 16)


# --- framing ---------------------------------------------------------------------------------

def frame_reply(text: str) -> bytes:
    """A text reply as sent by the device: ``text`` + 4 hex CRC + ``\\r``."""
    return (text + crc_hex(text) + "\r").encode("ascii")


def reply_length(buf: bytes | bytearray) -> int | None:
    """Length in bytes of the first complete reply at the start of ``buf``, or None when more
    bytes are needed. A BX reply (starting ``C4 A5``) is sized from its header, whose CRC is
    checked here; a text reply ends at the first ``\\r``.

    Raises ``ProtocolError`` when the header is corrupt or no ``\\r`` came within
    ``MAX_TEXT_REPLY`` bytes. For a BX reply the returned length may exceed ``len(buf)``:
    read until it is reached.
    """
    if not buf:
        return None
    if buf[0] == BX_START_BYTES[0]:
        if len(buf) < 2:
            return None
        if buf[1] != BX_START_BYTES[1]:
            raise ProtocolError(f"reply starts with C4 but not C4 A5: {bytes(buf[:8]).hex(' ')}",
                                device=DEVICE)
        if len(buf) < 6:
            return None
        head_crc = struct.unpack_from("<H", buf, 4)[0]
        if crc16(bytes(buf[:4])) != head_crc:
            raise ProtocolError(f"BX header CRC mismatch: {bytes(buf[:6]).hex(' ')}",
                                device=DEVICE)
        return struct.unpack_from("<H", buf, 2)[0] + 8
    i = bytes(buf[:MAX_TEXT_REPLY + 1]).find(b"\r")
    if i >= 0:
        return i + 1
    if len(buf) > MAX_TEXT_REPLY:
        raise ProtocolError(f"no CR within {MAX_TEXT_REPLY} bytes of reply", device=DEVICE)
    return None


def split_reply(raw: bytes | bytearray) -> str:
    """Check the CRC and framing of one text reply (``payload`` + CRC + ``\\r``) and return
    the payload (may contain LF). Raises ``ProtocolError`` quoting what was received."""
    data = bytes(raw)
    if not data.endswith(b"\r"):
        raise ProtocolError(f"torn reply (no CR): {data[:80]!r}", device=DEVICE)
    body = data[:-1]
    if b"\r" in body:
        raise ProtocolError(f"more than one reply in {data[:80]!r}", device=DEVICE)
    if len(body) < 4:
        raise ProtocolError(f"reply too short for a CRC: {data!r}", device=DEVICE)
    try:
        text = body.decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError(f"reply is not ASCII: {data[:80]!r}", device=DEVICE) from None
    payload, crc_field = text[:-4], text[-4:]
    if not _HEX_RE.fullmatch(crc_field):
        raise ProtocolError(f"reply CRC field {crc_field!r} is not hex in {data[:80]!r}",
                            device=DEVICE)
    if int(crc_field, 16) != crc16(payload):
        raise ProtocolError(f"reply CRC mismatch ({crc_field} != {crc_hex(payload)}) in "
                            f"{data[:80]!r}", device=DEVICE)
    return payload


# --- text replies ----------------------------------------------------------------------------

class ReplyKind(enum.StrEnum):
    """What a text reply is. A str: ``ReplyKind.OKAY == "okay"``."""

    OKAY = "okay"
    ERROR = "error"
    WARNING = "warning"
    RESET = "reset"
    DATA = "data"


@dataclass(frozen=True)
class Reply:
    """A decoded text reply. ``kind`` a :class:`ReplyKind`; ``text`` the payload without
    CRC; ``code`` / ``meaning`` for errors and warnings."""

    kind: ReplyKind
    text: str
    code: int | None = None
    meaning: str | None = None


def classify_reply(payload: str) -> Reply:
    """Classify a CRC-checked payload as OKAY / ERRORxx / WARNINGxx / RESET / data."""
    if payload == "OKAY":
        return Reply(ReplyKind.OKAY, payload)
    if payload == "RESET":
        return Reply(ReplyKind.RESET, payload)
    m = _ERR_RE.fullmatch(payload)
    if m:
        code = int(m.group(2), 16)
        if m.group(1) == "ERROR":
            return Reply(ReplyKind.ERROR, payload, code, error_text(code))
        return Reply(ReplyKind.WARNING, payload, code, warning_text(code))
    if payload.startswith("ERROR"):
        raise ProtocolError(f"malformed error reply {payload[:40]!r}", device=DEVICE)
    return Reply(ReplyKind.DATA, payload)


def parse_reply(raw: bytes | bytearray) -> Reply:
    """:func:`split_reply` + :func:`classify_reply` for one text reply."""
    return classify_reply(split_reply(raw))


def raise_for_error(reply: Reply, command: str, device: str = DEVICE) -> Reply:
    """Raise ``DeviceError(code=int, text=meaning, device=device)`` if ``reply`` is
    ``ERRORxx``; return it otherwise. ``command`` names the command in the message."""
    if reply.kind == ReplyKind.ERROR:
        assert reply.code is not None
        raise DeviceError(f"NDI {command} answered ERROR{reply.code:02X} ({reply.meaning})",
                          code=reply.code, text=reply.meaning, device=device)
    return reply


def encode_error(code: int) -> bytes:
    """The device's ``ERRORxx`` reply, framed."""
    return frame_reply(f"ERROR{code:02X}")


def encode_warning(code: int) -> bytes:
    """The device's ``WARNINGxx`` reply, framed."""
    return frame_reply(f"WARNING{code:02X}")


OKAY_REPLY = frame_reply("OKAY")
#: The reply a device sends after a reset (serial break).
RESET_REPLY = frame_reply("RESET")


# --- handle management and identity ----------------------------------------------------------

def encode_phsr(handles: Mapping[int, int] | Iterable[tuple[int, int]]) -> str:
    """PHSR payload: 2-hex count, then per handle 2-hex handle + 3-hex status."""
    items = list(handles.items()) if isinstance(handles, Mapping) else list(handles)
    return f"{len(items):02X}" + "".join(f"{h:02X}{s & 0xFFF:03X}" for h, s in items)


def decode_phsr(payload: str) -> list[tuple[int, int]]:
    """Decode a PHSR payload into [(handle, status), …]; ``ProtocolError`` if malformed.
    The status bits are :class:`~tmscal.drivers.ndi.codes.HandleStatus`."""
    if len(payload) < 2:
        raise ProtocolError(f"PHSR reply too short: {payload!r}", device=DEVICE)
    n = parse_hex(payload[:2], "PHSR count")
    if len(payload) != 2 + 5 * n:
        raise ProtocolError(f"PHSR reply announces {n} handles but is {len(payload)} chars: "
                            f"{payload[:80]!r}", device=DEVICE)
    return [(parse_hex(payload[2 + 5 * i:4 + 5 * i], "PHSR handle"),
             parse_hex(payload[4 + 5 * i:7 + 5 * i], "PHSR status")) for i in range(n)]


def decode_phrq(payload: str) -> int:
    """The handle (2 hex digits) of a PHRQ reply."""
    if len(payload) != 2:
        raise ProtocolError(f"PHRQ reply {payload[:20]!r} is not a 2-hex handle", device=DEVICE)
    return parse_hex(payload, "PHRQ handle")


def parse_ver(payload: str) -> dict[str, str]:
    """``key: value`` lines of a VER reply as a dict (plus ``"title"``: the first line)."""
    lines = [ln.strip() for ln in payload.replace("\r", "\n").split("\n") if ln.strip()]
    out: dict[str, str] = {}
    if lines:
        out["title"] = lines[0]
    for ln in lines:
        key, sep, value = ln.partition(":")
        if sep and key.strip():
            out[key.strip()] = value.strip()
    return out
