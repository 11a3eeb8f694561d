"""NDI Combined API codec (Polaris Vicra / Spectra): both directions in one module.

Used by the driver (:mod:`tmscal.drivers.ndi.tracker`) to encode commands and decode replies,
and by the mock (:mod:`tmscal.mocks.polaris`) to decode commands and encode replies, so the
two can never disagree on a layout. Facts: NDI's Polaris Application Program Interface Guide
(Combined API).

* CRC: CRC-16/ARC (poly 0x8005 reflected, init 0, no final XOR), :func:`crc16`.
* Commands: ``CMD:params`` + 4 uppercase hex CRC + ``\\r`` (colon form) or ``CMD params\\r``
  (space form, no CRC): :func:`encode_command`, :func:`parse_command`.
* Replies: text + 4 hex CRC + ``\\r`` (:func:`frame_reply`, :func:`parse_reply`); binary BX
  replies carry their own header and CRCs (:func:`encode_bx`, :func:`decode_bx`).
  :func:`reply_length` finds where the first complete reply in a byte buffer ends.
* Tracking data (TX / BX): per port handle a :class:`HandleRecord` with the pose
  ``tracker_from_tool`` as a 4×4 matrix in mm (from NDI's q0-first quaternion and mm
  translation via :mod:`tmscal.geometry`), the RMS fit error in mm, the port status word and
  the 32-bit frame number; plus the system status word.

Errors: :class:`~tmscal.errors.ProtocolError` for bytes that do not parse (bad framing, CRC
mismatch, torn or malformed replies; the message quotes what was received);
:class:`~tmscal.errors.DeviceError` with ``code`` (int NDI error code) and ``text`` (its
meaning) for ``ERRORxx`` replies.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ...errors import DeviceError, ProtocolError
from ...geometry import make_pose, matrix_from_quaternion, quaternion_from_matrix

DEVICE = "ndi"

# --- CRC ------------------------------------------------------------------------------------


def _make_table() -> list[int]:
    table = []
    for byte in range(256):
        c = byte
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
        table.append(c)
    return table


_CRC_TABLE = _make_table()


def crc16(data: bytes | bytearray | memoryview | str, crc: int = 0) -> int:
    """CRC-16/ARC of ``data`` (str is encoded as ASCII), continuing from ``crc``.

    ``crc16(b"123456789") == 0xBB3D``; ``crc16(b"OKAY") == 0xA896``.
    """
    if isinstance(data, str):
        data = data.encode("ascii")
    table = _CRC_TABLE
    for b in bytes(data):
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc


def crc_hex(data: bytes | str) -> str:
    """The CRC of ``data`` as 4 uppercase hex digits, as NDI appends it to text."""
    return f"{crc16(data):04X}"


# --- codes and their meanings ----------------------------------------------------------------

#: ``ERRORxx`` code -> meaning (NDI Combined API).
ERROR_TEXTS: dict[int, str] = {
    0x01: "invalid command",
    0x02: "command too long",
    0x03: "command too short",
    0x04: "invalid CRC calculated for command",
    0x05: "time-out on command execution",
    0x06: "unable to set up new communication parameters",
    0x07: "incorrect number of command parameters",
    0x08: "invalid port handle selected",
    0x09: "invalid tracking priority selected (must be S, D or B)",
    0x0A: "invalid LED selected",
    0x0B: "invalid LED state selected",
    0x0C: "command is invalid while in the current mode",
    0x0D: "no tool assigned to the selected port handle",
    0x0E: "selected port handle not initialised",
    0x0F: "selected port handle not enabled",
    0x10: "system not initialised",
    0x11: "unable to stop tracking",
    0x12: "unable to start tracking",
    0x13: "unable to initialise tool",
    0x14: "invalid characterisation parameters",
    0x15: "unable to initialise the measurement system",
    0x16: "unable to start diagnostic mode",
    0x17: "unable to stop diagnostic mode",
    0x19: "unable to read the device's firmware version",
    0x1A: "internal measurement system error",
    0x1C: "invalid marker activation signature",
    0x1E: "unable to read SROM data",
    0x1F: "unable to write SROM data",
    0x21: "unable to perform tool current test",
    0x22: "wavelength of an enabled tool not supported",
    0x23: "command parameter out of range",
    0x24: "unable to select parameters by volume",
    0x25: "unable to determine the supported features list",
    0x28: "too many tools",
    0x2A: "no memory available (heap full)",
    0x2B: "port handle not allocated",
    0x2C: "port handle unoccupied",
    0x2D: "no more port handles available",
    0x2E: "incompatible firmware versions",
    0x2F: "invalid port description",
    0x30: "requested port already has a handle",
    0x32: "invalid operation for this port handle",
    0x33: "feature unavailable",
    0x3B: "file not found",
    0x3C: "write error",
    0x3D: "read error",
    0x40: "invalid tool definition",
    0x41: "tool exceeds the maximum markers, faces or groups",
    0x42: "device not present",
    0xF1: "too much environmental infrared",
    0xF4: "unable to erase flash SROM",
    0xF5: "unable to write flash SROM",
    0xF6: "unable to read flash SROM",
}

#: ``WARNINGxx`` code -> meaning. ndicapi treats warnings as success.
WARNING_TEXTS: dict[int, str] = {
    0x01: "possible hardware fault",
    0x02: "tool violates unique geometry",
    0x03: "tool is not compatible with the loaded tools",
    0x04: "tool violates unique geometry and is not compatible with the loaded tools",
    0x05: "no marker wavelength for the tool",
}


def error_text(code: int) -> str:
    """Meaning of NDI error ``code`` (e.g. 0x0C), or ``"unknown error 0xNN"``."""
    return ERROR_TEXTS.get(code, f"unknown error 0x{code:02X}")


def warning_text(code: int) -> str:
    """Meaning of NDI warning ``code``, or ``"unknown warning 0xNN"``."""
    return WARNING_TEXTS.get(code, f"unknown warning 0x{code:02X}")


# Port status bits (TX: 8 hex digits; BX: uint32)
PORT_OCCUPIED = 0x01
PORT_SWITCH_1 = 0x02
PORT_SWITCH_2 = 0x04
PORT_SWITCH_3 = 0x08
PORT_INITIALIZED = 0x10
PORT_ENABLED = 0x20
PORT_OUT_OF_VOLUME = 0x40
PORT_PARTIALLY_OUT_OF_VOLUME = 0x80
PORT_ALGORITHM_LIMITATION = 0x100
PORT_IR_INTERFERENCE = 0x200
PORT_PROCESSING_EXCEPTION = 0x1000
PORT_FELL_BEHIND = 0x4000
PORT_DATA_BUFFER_LIMITATION = 0x8000
#: A healthy, enabled tool.
PORT_HEALTHY = PORT_OCCUPIED | PORT_INITIALIZED | PORT_ENABLED

# System status bits (TX: 4 hex digits; BX: uint16)
SYS_COMM_SYNC_ERROR = 0x01
SYS_TOO_MUCH_IR = 0x02
SYS_CRC_ERROR = 0x04
SYS_RECOVERABLE_EXCEPTION = 0x08
SYS_HARDWARE_FAILURE = 0x10
SYS_HARDWARE_CHANGE = 0x20
SYS_PORT_OCCUPIED = 0x40
SYS_PORT_UNOCCUPIED = 0x80
SYS_DIAGNOSTICS_PENDING = 0x100
SYS_TEMPERATURE = 0x200

# PHSR handle status (3 hex digits)
HANDLE_OCCUPIED = 0x001
HANDLE_INITIALIZED = 0x010
HANDLE_ENABLED = 0x020

# TX / BX reply options
OPT_TRANSFORMS = 0x0001
OPT_OUT_OF_VOLUME = 0x0800

# BX handle status byte
BX_VALID = 0x01
BX_MISSING = 0x02
BX_DISABLED = 0x04

#: COMM baud-rate codes (first COMM parameter).
BAUD_CODES: dict[int, str] = {
    9600: "0", 14400: "1", 19200: "2", 38400: "3", 57600: "4", 115200: "5", 921600: "6",
    1228739: "7", 230400: "A",
}
BAUD_FROM_CODE: dict[str, int] = {v: k for k, v in BAUD_CODES.items()}

#: The reply a device sends after a reset (serial break).
RESET_REPLY = b"RESETBE6F\r"
#: Longest text reply we accept before calling the stream garbage.
MAX_TEXT_REPLY = 65536
BX_START = 0xA5C4
_BX_START_BYTES = b"\xc4\xa5"


# --- commands --------------------------------------------------------------------------------

_NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9]*")


def encode_command(name: str, params: str = "", *, crc: bool = True) -> bytes:
    """Bytes for command ``name`` with ``params``.

    ``crc=True``: colon form ``NAME:params`` + CRC (4 uppercase hex of everything from the
    first letter through the last parameter) + ``\\r``. ``crc=False``: space form
    ``NAME params\\r``. ``encode_command("INIT") == b"INIT:E3A5\\r"``.
    """
    if not _NAME_RE.fullmatch(name):
        raise ValueError(f"invalid NDI command name {name!r}")
    if "\r" in params or "\n" in params:
        raise ValueError(f"NDI command parameters must not contain CR/LF: {params!r}")
    if crc:
        body = f"{name.upper()}:{params}"
        return (body + crc_hex(body) + "\r").encode("ascii")
    return f"{name.upper()} {params}\r".encode("ascii")


@dataclass(frozen=True)
class Command:
    """A decoded command: upper-case ``name``, raw ``params`` (case kept) and whether it
    came in the colon form with a (valid) CRC."""

    name: str
    params: str
    had_crc: bool


def parse_command(line: bytes) -> Command:
    """Decode one command line (with or without its trailing ``\\r``).

    Raises ``ProtocolError`` with ``code=0x04`` when the CRC of a colon-form command does not
    match, ``code=0x01`` when the line is not a command at all (non-ASCII, no name).
    """
    raw = bytes(line)
    if raw.endswith(b"\r"):
        raw = raw[:-1]
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError(f"command is not ASCII: {raw[:40]!r}", code=0x01,
                            text=error_text(0x01), device=DEVICE) from None
    colon = text.find(":")
    space = text.find(" ")
    if colon >= 0 and (space < 0 or colon < space):
        name, rest = text[:colon], text[colon + 1:]
        if len(rest) < 4:
            raise ProtocolError(f"command {text!r} has no CRC", code=0x04,
                                text=error_text(0x04), device=DEVICE)
        params, crc_field = rest[:-4], rest[-4:]
        expected = crc_hex(text[:-4])
        if crc_field.upper() != expected:
            raise ProtocolError(f"command {text!r}: CRC {crc_field!r} != {expected}",
                                code=0x04, text=error_text(0x04), device=DEVICE)
        had_crc = True
    elif space >= 0:
        name, params, had_crc = text[:space], text[space + 1:], False
    else:
        name, params, had_crc = text, "", False
    if not _NAME_RE.fullmatch(name):
        raise ProtocolError(f"not a command: {text[:40]!r}", code=0x01, text=error_text(0x01),
                            device=DEVICE)
    return Command(name.upper(), params, had_crc)


# --- reply framing ---------------------------------------------------------------------------

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
    if buf[0] == 0xC4:
        if len(buf) < 2:
            return None
        if buf[1] != 0xA5:
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


@dataclass(frozen=True)
class Reply:
    """A decoded text reply. ``kind`` is "okay", "error", "warning", "reset" or "data";
    ``text`` the payload without CRC; ``code`` / ``meaning`` for errors and warnings."""

    kind: str
    text: str
    code: int | None = None
    meaning: str | None = None


_ERR_RE = re.compile(r"(ERROR|WARNING)([0-9A-Fa-f]{2})")


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


def classify_reply(payload: str) -> Reply:
    """Classify a CRC-checked payload as OKAY / ERRORxx / WARNINGxx / RESET / data."""
    if payload == "OKAY":
        return Reply("okay", payload)
    if payload == "RESET":
        return Reply("reset", payload)
    m = _ERR_RE.fullmatch(payload)
    if m:
        code = int(m.group(2), 16)
        if m.group(1) == "ERROR":
            return Reply("error", payload, code, error_text(code))
        return Reply("warning", payload, code, warning_text(code))
    if payload.startswith("ERROR"):
        raise ProtocolError(f"malformed error reply {payload[:40]!r}", device=DEVICE)
    return Reply("data", payload)


def parse_reply(raw: bytes | bytearray) -> Reply:
    """:func:`split_reply` + :func:`classify_reply` for one text reply."""
    return classify_reply(split_reply(raw))


def raise_for_error(reply: Reply, command: str) -> Reply:
    """Raise ``DeviceError(code=int, text=meaning)`` if ``reply`` is ``ERRORxx``; return it
    otherwise. ``command`` names the command in the message."""
    if reply.kind == "error":
        assert reply.code is not None
        raise DeviceError(f"NDI {command} answered ERROR{reply.code:02X} ({reply.meaning})",
                          code=reply.code, text=reply.meaning, device=DEVICE)
    return reply


def encode_error(code: int) -> bytes:
    """The device's ``ERRORxx`` reply, framed."""
    return frame_reply(f"ERROR{code:02X}")


def encode_warning(code: int) -> bytes:
    """The device's ``WARNINGxx`` reply, framed."""
    return frame_reply(f"WARNING{code:02X}")


OKAY_REPLY = frame_reply("OKAY")


# --- tracking records ------------------------------------------------------------------------

VALID = "valid"
MISSING = "missing"
DISABLED = "disabled"


@dataclass(frozen=True)
class HandleRecord:
    """One port handle in a TX/BX reply.

    ``status`` is "valid", "missing" or "disabled". For a valid record ``quaternion`` is
    (q0, qx, qy, qz), ``translation_mm`` (x, y, z) in mm, ``error_mm`` the RMS fit error in
    mm and ``pose`` tracker_from_tool, 4×4 float64 in mm. ``port_status`` is the raw port
    status word and ``frame`` the device's 32-bit frame number (None for disabled records).
    """

    handle: int
    status: str
    port_status: int = 0
    frame: int | None = None
    quaternion: tuple[float, float, float, float] | None = None
    translation_mm: tuple[float, float, float] | None = None
    error_mm: float | None = None
    pose: np.ndarray | None = field(default=None, compare=False, repr=False)

    @property
    def missing(self) -> bool:
        return self.status != VALID

    @property
    def out_of_volume(self) -> bool:
        return bool(self.port_status & PORT_OUT_OF_VOLUME)

    @property
    def partially_out_of_volume(self) -> bool:
        return bool(self.port_status & PORT_PARTIALLY_OUT_OF_VOLUME)

    @property
    def ir_interference(self) -> bool:
        return bool(self.port_status & PORT_IR_INTERFERENCE)

    @classmethod
    def valid(cls, handle: int, quaternion: Sequence[float], translation_mm: Sequence[float],
              error_mm: float, port_status: int, frame: int,
              pose: np.ndarray | None = None) -> HandleRecord:
        """A valid record; the pose is computed from the quaternion and translation unless
        given. Raises ``ProtocolError`` for a non-finite or zero-length quaternion."""
        q = tuple(float(v) for v in quaternion)
        t = tuple(float(v) for v in translation_mm)
        if len(q) != 4 or len(t) != 3:
            raise ValueError("quaternion needs 4 and translation 3 values")
        vals = q + t + (float(error_mm),)
        if not all(math.isfinite(v) for v in vals):
            raise ProtocolError(f"handle {handle:02X}: non-finite transform {vals}",
                                device=DEVICE)
        if math.sqrt(sum(v * v for v in q)) < 1e-6:
            raise ProtocolError(f"handle {handle:02X}: zero-length quaternion", device=DEVICE)
        if pose is None:
            pose = make_pose(matrix_from_quaternion(np.array(q)), np.array(t))
        elif pose is _DEFERRED:
            pose = None  # filled in by _fill_poses (batched conversion)
        return cls(handle, VALID, int(port_status), int(frame), q, t,  # type: ignore[arg-type]
                   float(error_mm), pose)

    @classmethod
    def from_pose(cls, handle: int, tracker_from_tool: np.ndarray, error_mm: float,
                  port_status: int, frame: int) -> HandleRecord:
        """A valid record from a 4×4 pose (tracker_from_tool, mm); used by the mock."""
        T = np.asarray(tracker_from_tool, dtype=np.float64)
        q = quaternion_from_matrix(T[:3, :3])
        return cls.valid(handle, q.tolist(), T[:3, 3].tolist(), error_mm, port_status, frame,
                         pose=T.copy())

    @classmethod
    def missing_tool(cls, handle: int, port_status: int, frame: int) -> HandleRecord:
        """A record for a tool that is enabled but not seen."""
        return cls(handle, MISSING, int(port_status), int(frame))


_DEFERRED = np.empty((0,))


def _fill_poses(records: list[HandleRecord]) -> list[HandleRecord]:
    """Compute the poses of valid records whose pose was deferred, in one batched call."""
    idx = [i for i, r in enumerate(records) if r.status == VALID and r.pose is None]
    if idx:
        q = np.array([records[i].quaternion for i in idx], dtype=np.float64)
        t = np.array([records[i].translation_mm for i in idx], dtype=np.float64)
        poses = make_pose(matrix_from_quaternion(q), t)
        for k, i in enumerate(idx):
            object.__setattr__(records[i], "pose", poses[k])
    return records


def records_from_poses(items: Sequence[tuple[int, np.ndarray, float, int, int]]
                       ) -> list[HandleRecord]:
    """Valid records from (handle, tracker_from_tool 4×4 mm, error_mm, port_status, frame)
    tuples, converting all rotations to quaternions in one batched call (used by the mock)."""
    if not items:
        return []
    T = np.array([it[1] for it in items], dtype=np.float64)
    q = quaternion_from_matrix(T[:, :3, :3])
    return [HandleRecord.valid(h, q[k].tolist(), T[k, :3, 3].tolist(), err, port, frame,
                               pose=T[k].copy())
            for k, (h, _, err, port, frame) in enumerate(items)]


@dataclass(frozen=True)
class TrackingReply:
    """A decoded TX or BX reply: the per-handle records in reply order and the system
    status word."""

    records: tuple[HandleRecord, ...]
    system_status: int = 0

    def by_handle(self) -> dict[int, HandleRecord]:
        return {r.handle: r for r in self.records}

    @property
    def frame(self) -> int | None:
        """The frame number (the largest over the records), or None when there is none."""
        frames = [r.frame for r in self.records if r.frame is not None]
        return max(frames) if frames else None


# --- TX --------------------------------------------------------------------------------------

_TX_VALID_RE = re.compile(
    r"([+-][0-9]{5})([+-][0-9]{5})([+-][0-9]{5})([+-][0-9]{5})([+-][0-9]{6})([+-][0-9]{6})([+-][0-9]{6})"
    r"([+-][0-9]{5})([0-9A-Fa-f]{8})([0-9A-Fa-f]{8})")
_TX_MISSING_RE = re.compile(r"MISSING([0-9A-Fa-f]{8})([0-9A-Fa-f]{8})")
_HEX_RE = re.compile(r"[0-9A-Fa-f]+")


def _hex(s: str, what: str) -> int:
    if not s or not _HEX_RE.fullmatch(s):
        raise ProtocolError(f"{what}: {s[:20]!r} is not hex", device=DEVICE)
    return int(s, 16)


def decode_tx(payload: str) -> TrackingReply:
    """Decode the payload of a TX reply (options 0001/0801; CRC already checked).

    Layout: 2-hex handle count, then per handle ``hh`` + transform (Q0 Qx Qy Qz sign+5 ×1e-4,
    Tx Ty Tz sign+6 ×0.01 mm, error sign+5 ×1e-4 mm) or ``MISSING``, port status (8 hex),
    frame (8 hex), LF; finally the system status (4 hex). ``DISABLED`` rows are accepted
    with or without status and frame. Raises ``ProtocolError`` on any deviation.
    """
    if len(payload) < 2:
        raise ProtocolError(f"TX reply too short: {payload!r}", device=DEVICE)
    count = _hex(payload[:2], "TX handle count")
    parts = payload[2:].split("\n")
    if len(parts) != count + 1:
        raise ProtocolError(f"TX reply announces {count} handles but has {len(parts) - 1} "
                            f"rows: {payload[:80]!r}", device=DEVICE)
    records = []
    for row in parts[:-1]:
        handle = _hex(row[:2], "TX port handle") if len(row) >= 2 else -1
        if handle < 0:
            raise ProtocolError(f"TX row too short: {row!r}", device=DEVICE)
        body = row[2:]
        m = _TX_VALID_RE.fullmatch(body)
        if m:
            g = m.groups()
            q = [int(v) * 1e-4 for v in g[0:4]]
            t = [int(v) * 0.01 for v in g[4:7]]
            records.append(HandleRecord.valid(handle, q, t, int(g[7]) * 1e-4, int(g[8], 16),
                                              int(g[9], 16), pose=_DEFERRED))
            continue
        m = _TX_MISSING_RE.fullmatch(body)
        if m:
            records.append(HandleRecord.missing_tool(handle, int(m.group(1), 16),
                                                     int(m.group(2), 16)))
            continue
        if body.startswith("DISABLED"):
            records.append(HandleRecord(handle, DISABLED))
            continue
        raise ProtocolError(f"TX row for handle {handle:02X} does not parse: {row[:80]!r}",
                            device=DEVICE)
    tail = parts[-1]
    if len(tail) != 4:
        raise ProtocolError(f"TX system status {tail!r} is not 4 hex digits", device=DEVICE)
    return TrackingReply(tuple(_fill_poses(records)), _hex(tail, "TX system status"))


def _signed(value: float, scale: float, digits: int) -> str:
    limit = 10 ** digits - 1
    n = max(-limit, min(limit, int(round(value * scale))))
    return f"{n:+0{digits + 1}d}"


def encode_tx(records: Iterable[HandleRecord], system_status: int = 0) -> str:
    """The payload of a TX reply (frame it with :func:`frame_reply`). Disabled records are
    skipped (clients disagree on their layout); values beyond the field width are clamped."""
    rows = []
    for r in records:
        if r.status == DISABLED:
            continue
        head = f"{r.handle:02X}"
        tail = f"{r.port_status & 0xFFFFFFFF:08X}{(r.frame or 0) & 0xFFFFFFFF:08X}\n"
        if r.status == MISSING:
            rows.append(head + "MISSING" + tail)
            continue
        assert r.quaternion is not None and r.translation_mm is not None
        q = "".join(_signed(v, 1e4, 5) for v in r.quaternion)
        t = "".join(_signed(v, 1e2, 6) for v in r.translation_mm)
        rows.append(head + q + t + _signed(r.error_mm or 0.0, 1e4, 5) + tail)
    return f"{len(rows):02X}" + "".join(rows) + f"{system_status & 0xFFFF:04X}"


# --- BX --------------------------------------------------------------------------------------

def encode_bx(records: Iterable[HandleRecord], system_status: int = 0) -> bytes:
    """A complete BX reply (header, header CRC, body, body CRC), little-endian throughout.
    Floats are float32; the frame and port status uint32; the system status uint16."""
    recs = list(records)
    body = bytearray([len(recs) & 0xFF])
    for r in recs:
        if r.status == VALID:
            assert r.quaternion is not None and r.translation_mm is not None
            body += bytes([r.handle & 0xFF, BX_VALID])
            body += struct.pack("<8f", *r.quaternion, *r.translation_mm, r.error_mm or 0.0)
            body += struct.pack("<II", r.port_status & 0xFFFFFFFF, (r.frame or 0) & 0xFFFFFFFF)
        elif r.status == MISSING:
            body += bytes([r.handle & 0xFF, BX_MISSING])
            body += struct.pack("<II", r.port_status & 0xFFFFFFFF, (r.frame or 0) & 0xFFFFFFFF)
        else:
            body += bytes([r.handle & 0xFF, BX_DISABLED])
    body += struct.pack("<H", system_status & 0xFFFF)
    head = struct.pack("<HH", BX_START, len(body))
    return head + struct.pack("<H", crc16(head)) + bytes(body) + struct.pack("<H", crc16(body))


def check_bx(raw: bytes | bytearray) -> bytes:
    """Check the framing of one complete BX reply (start sequence, header CRC, length, body
    CRC) without decoding the body; returns the body. ``ProtocolError`` otherwise."""
    data = bytes(raw)
    if len(data) < 8:
        raise ProtocolError(f"BX reply too short ({len(data)} bytes): {data.hex(' ')}",
                            device=DEVICE)
    start, n, head_crc = struct.unpack_from("<HHH", data, 0)
    if start != BX_START:
        raise ProtocolError(f"BX start sequence {data[:2].hex(' ')} != c4 a5", device=DEVICE)
    if crc16(data[:4]) != head_crc:
        raise ProtocolError(f"BX header CRC mismatch: {data[:6].hex(' ')}", device=DEVICE)
    if len(data) != n + 8:
        raise ProtocolError(f"torn BX reply: header says {n + 8} bytes, got {len(data)}",
                            device=DEVICE)
    body = data[6:6 + n]
    body_crc = struct.unpack_from("<H", data, 6 + n)[0]
    if crc16(body) != body_crc:
        raise ProtocolError(f"BX body CRC mismatch ({body_crc:04X} != {crc16(body):04X})",
                            device=DEVICE)
    return body


def decode_bx(raw: bytes | bytearray) -> TrackingReply:
    """Decode one complete BX reply (options 0001/0801). Checks the start sequence, both
    CRCs and that the body is consumed exactly; raises ``ProtocolError`` otherwise."""
    body = check_bx(raw)
    try:
        pos = 0
        count = body[pos]
        pos += 1
        records = []
        for _ in range(count):
            handle, status = body[pos], body[pos + 1]
            pos += 2
            if status == BX_VALID:
                vals = struct.unpack_from("<8f", body, pos)
                pos += 32
                port, frame = struct.unpack_from("<II", body, pos)
                pos += 8
                records.append(HandleRecord.valid(handle, vals[0:4], vals[4:7], vals[7], port,
                                                  frame, pose=_DEFERRED))
            elif status == BX_MISSING:
                port, frame = struct.unpack_from("<II", body, pos)
                pos += 8
                records.append(HandleRecord.missing_tool(handle, port, frame))
            elif status == BX_DISABLED:
                records.append(HandleRecord(handle, DISABLED))
            else:
                raise ProtocolError(f"BX handle {handle:02X}: unknown status 0x{status:02X}",
                                    device=DEVICE)
        (system_status,) = struct.unpack_from("<H", body, pos)
        pos += 2
    except (IndexError, struct.error):
        raise ProtocolError(f"BX body shorter than its {len(body)}-byte content implies",
                            device=DEVICE) from None
    if pos != len(body):
        raise ProtocolError(f"BX body has {len(body) - pos} unexplained trailing bytes",
                            device=DEVICE)
    return TrackingReply(tuple(_fill_poses(records)), system_status)


# --- handle management replies ---------------------------------------------------------------

def encode_phsr(handles: Mapping[int, int] | Iterable[tuple[int, int]]) -> str:
    """PHSR payload: 2-hex count, then per handle 2-hex handle + 3-hex status."""
    items = list(handles.items()) if isinstance(handles, Mapping) else list(handles)
    return f"{len(items):02X}" + "".join(f"{h:02X}{s & 0xFFF:03X}" for h, s in items)


def decode_phsr(payload: str) -> list[tuple[int, int]]:
    """Decode a PHSR payload into [(handle, status), …]; ``ProtocolError`` if malformed."""
    if len(payload) < 2:
        raise ProtocolError(f"PHSR reply too short: {payload!r}", device=DEVICE)
    n = _hex(payload[:2], "PHSR count")
    if len(payload) != 2 + 5 * n:
        raise ProtocolError(f"PHSR reply announces {n} handles but is {len(payload)} chars: "
                            f"{payload[:80]!r}", device=DEVICE)
    return [(_hex(payload[2 + 5 * i:4 + 5 * i], "PHSR handle"),
             _hex(payload[4 + 5 * i:7 + 5 * i], "PHSR status")) for i in range(n)]


def decode_phrq(payload: str) -> int:
    """The handle (2 hex digits) of a PHRQ reply."""
    if len(payload) != 2:
        raise ProtocolError(f"PHRQ reply {payload[:20]!r} is not a 2-hex handle", device=DEVICE)
    return _hex(payload, "PHRQ handle")


def pvwr_params(handle: int, address: int, chunk: bytes) -> str:
    """PVWR parameters: ``hh`` + ``aaaa`` + 128 uppercase hex chars for a 64-byte chunk."""
    if len(chunk) != 64:
        raise ValueError(f"PVWR chunks are 64 bytes, got {len(chunk)}")
    return f"{handle:02X}{address:04X}{chunk.hex().upper()}"


def rom_chunks(rom: bytes, pad_to: int = 64) -> list[tuple[int, bytes]]:
    """Split a tool definition into (address, 64-byte chunk) pairs, zero-padded to a multiple
    of ``pad_to`` (64; ndicapi uses 1024)."""
    if pad_to % 64:
        raise ValueError("pad_to must be a multiple of 64")
    size = max(pad_to, -(-len(rom) // pad_to) * pad_to)
    data = rom + bytes(size - len(rom))
    return [(a, data[a:a + 64]) for a in range(0, size, 64)]


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


__all__ = [
    "crc16", "crc_hex", "ERROR_TEXTS", "WARNING_TEXTS", "error_text", "warning_text",
    "encode_command", "parse_command", "Command", "frame_reply", "reply_length", "Reply",
    "split_reply", "classify_reply", "parse_reply", "raise_for_error", "encode_error",
    "encode_warning", "OKAY_REPLY", "HandleRecord", "TrackingReply", "decode_tx", "encode_tx",
    "encode_bx", "decode_bx", "check_bx", "encode_phsr", "decode_phsr", "decode_phrq",
    "pvwr_params", "records_from_poses",
    "rom_chunks", "parse_ver", "BAUD_CODES", "BAUD_FROM_CODE", "RESET_REPLY",
]
