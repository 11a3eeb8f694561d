"""NDI Combined API tracking replies, both directions: TX (text) and BX (binary).

Per port handle a :class:`HandleRecord` with the pose ``tracker_from_tool`` as a 4×4 matrix
in mm (from NDI's q0-first quaternion and mm translation via :mod:`tmscal.geometry`), the RMS
fit error in mm, the port status word (:class:`~tmscal.drivers.ndi.codes.PortStatus`) and
the 32-bit frame number; per reply the system status word
(:class:`~tmscal.drivers.ndi.codes.SystemStatus`). Layouts: NDI's Polaris Application
Program Interface Guide, TX and BX (reply options 0001 and 0801).
"""

from __future__ import annotations

import enum
import functools
import math
import re
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ...errors import ProtocolError
from ...geometry import make_pose, matrix_from_quaternion, quaternion_from_matrix
from .codes import DEVICE, BxStatus, PortStatus, SystemStatus
from .crc import crc16
from .replies import BX_START, parse_hex

__all__ = [
    "RecordStatus", "HandleRecord", "TrackingReply", "records_from_poses", "decode_tx",
    "encode_tx", "encode_bx", "check_bx", "decode_bx",
]


class RecordStatus(enum.StrEnum):
    """Whether a port handle's record carries a pose. A str: ``RecordStatus.VALID ==
    "valid"``."""

    VALID = "valid"
    MISSING = "missing"
    DISABLED = "disabled"
    #: the port handle has no tool any more (a wired tool unplugged): TX ``hhUNOCCUPIED``
    UNOCCUPIED = "unoccupied"


VALID, MISSING, DISABLED = RecordStatus.VALID, RecordStatus.MISSING, RecordStatus.DISABLED
UNOCCUPIED = RecordStatus.UNOCCUPIED
_OUT_OF_VOLUME = int(PortStatus.OUT_OF_VOLUME)
_PARTIALLY_OUT_OF_VOLUME = int(PortStatus.PARTIALLY_OUT_OF_VOLUME)
_IR_INTERFERENCE = int(PortStatus.IR_INTERFERENCE)

# constructing an IntFlag costs about a microsecond; every record and reply needs one
_port_status = functools.lru_cache(maxsize=1024)(PortStatus)
_system_status = functools.lru_cache(maxsize=1024)(SystemStatus)


@dataclass(frozen=True)
class HandleRecord:
    """One port handle in a TX/BX reply.

    ``status`` is a :class:`RecordStatus`. For a valid record ``quaternion`` is
    (q0, qx, qy, qz), ``translation_mm`` (x, y, z) in mm, ``error_mm`` the RMS fit error in
    mm and ``pose`` tracker_from_tool, 4×4 float64 in mm. ``port_status`` is the port status
    word (a :class:`PortStatus`, an int) and ``frame`` the device's 32-bit frame number (None
    for disabled records).
    """

    handle: int
    status: RecordStatus
    port_status: PortStatus = PortStatus(0)
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
        return bool(int(self.port_status) & _OUT_OF_VOLUME)

    @property
    def partially_out_of_volume(self) -> bool:
        return bool(int(self.port_status) & _PARTIALLY_OUT_OF_VOLUME)

    @property
    def ir_interference(self) -> bool:
        return bool(int(self.port_status) & _IR_INTERFERENCE)

    @classmethod
    def valid(cls, handle: int, quaternion: Sequence[float], translation_mm: Sequence[float],
              error_mm: float, port_status: int, frame: int,
              pose: np.ndarray | None = None, batched: bool = False) -> HandleRecord:
        """A valid record; the pose is computed from the quaternion and translation unless
        given, or left to ``_fill_poses`` (one vectorised conversion per reply) when
        ``batched``. Raises ``ProtocolError`` for a non-finite or zero-length quaternion."""
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
        if pose is None and not batched:
            pose = make_pose(matrix_from_quaternion(np.array(q)), np.array(t))
        return cls(handle, VALID, _port_status(int(port_status)), int(frame),
                   q, t,  # type: ignore[arg-type]
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
        return cls(handle, MISSING, _port_status(int(port_status)), int(frame))


def _fill_poses(records: list[HandleRecord]) -> list[HandleRecord]:
    """The records, with the poses of valid records built with ``batched=True`` computed in
    one vectorised conversion (new records; the dataclass stays frozen)."""
    idx = [i for i, r in enumerate(records) if r.status == VALID and r.pose is None]
    if idx:
        q = np.array([records[i].quaternion for i in idx], dtype=np.float64)
        t = np.array([records[i].translation_mm for i in idx], dtype=np.float64)
        poses = make_pose(matrix_from_quaternion(q), t)
        records = list(records)
        for k, i in enumerate(idx):
            records[i] = replace(records[i], pose=poses[k])
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
    status word (a :class:`SystemStatus`, an int)."""

    records: tuple[HandleRecord, ...]
    system_status: SystemStatus = SystemStatus(0)

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


def decode_tx(payload: str) -> TrackingReply:
    """Decode the payload of a TX reply (options 0001/0801; CRC already checked).

    Layout: 2-hex handle count, then per handle ``hh`` + transform (Q0 Qx Qy Qz sign+5 ×1e-4,
    Tx Ty Tz sign+6 ×0.01 mm, error sign+5 ×1e-4 mm) or ``MISSING``, port status (8 hex),
    frame (8 hex), LF; finally the system status (4 hex). ``DISABLED`` rows are accepted
    with or without status and frame; ``UNOCCUPIED`` rows (a handle whose tool went away)
    carry nothing else and count in the handle count, as ndicapi reads them. Raises
    ``ProtocolError`` on any deviation.
    """
    if len(payload) < 2:
        raise ProtocolError(f"TX reply too short: {payload!r}", device=DEVICE)
    count = parse_hex(payload[:2], "TX handle count")
    parts = payload[2:].split("\n")
    if len(parts) != count + 1:
        raise ProtocolError(f"TX reply announces {count} handles but has {len(parts) - 1} "
                            f"rows: {payload[:80]!r}", device=DEVICE)
    records = []
    for row in parts[:-1]:
        handle = parse_hex(row[:2], "TX port handle") if len(row) >= 2 else -1
        if handle < 0:
            raise ProtocolError(f"TX row too short: {row!r}", device=DEVICE)
        body = row[2:]
        m = _TX_VALID_RE.fullmatch(body)
        if m:
            g = m.groups()
            q = [int(v) * 1e-4 for v in g[0:4]]
            t = [int(v) * 0.01 for v in g[4:7]]
            records.append(HandleRecord.valid(handle, q, t, int(g[7]) * 1e-4, int(g[8], 16),
                                              int(g[9], 16), batched=True))
            continue
        m = _TX_MISSING_RE.fullmatch(body)
        if m:
            records.append(HandleRecord.missing_tool(handle, int(m.group(1), 16),
                                                     int(m.group(2), 16)))
            continue
        if body.startswith("DISABLED"):
            records.append(HandleRecord(handle, DISABLED))
            continue
        if body == "UNOCCUPIED":
            records.append(HandleRecord(handle, UNOCCUPIED))
            continue
        raise ProtocolError(f"TX row for handle {handle:02X} does not parse: {row[:80]!r}",
                            device=DEVICE)
    tail = parts[-1]
    if len(tail) != 4:
        raise ProtocolError(f"TX system status {tail!r} is not 4 hex digits", device=DEVICE)
    return TrackingReply(tuple(_fill_poses(records)),
                         _system_status(parse_hex(tail, "TX system status")))


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
        if r.status == UNOCCUPIED:
            rows.append(head + "UNOCCUPIED\n")
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
            body += bytes([r.handle & 0xFF, BxStatus.VALID])
            body += struct.pack("<8f", *r.quaternion, *r.translation_mm, r.error_mm or 0.0)
            body += struct.pack("<II", r.port_status & 0xFFFFFFFF, (r.frame or 0) & 0xFFFFFFFF)
        elif r.status in (MISSING, UNOCCUPIED):  # BX has no UNOCCUPIED status: missing
            body += bytes([r.handle & 0xFF, BxStatus.MISSING])
            body += struct.pack("<II", r.port_status & 0xFFFFFFFF, (r.frame or 0) & 0xFFFFFFFF)
        else:
            body += bytes([r.handle & 0xFF, BxStatus.DISABLED])
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
            if status == BxStatus.VALID:
                vals = struct.unpack_from("<8f", body, pos)
                pos += 32
                port, frame = struct.unpack_from("<II", body, pos)
                pos += 8
                records.append(HandleRecord.valid(handle, vals[0:4], vals[4:7], vals[7], port,
                                                  frame, batched=True))
            elif status == BxStatus.MISSING:
                port, frame = struct.unpack_from("<II", body, pos)
                pos += 8
                records.append(HandleRecord.missing_tool(handle, port, frame))
            elif status == BxStatus.DISABLED:
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
    return TrackingReply(tuple(_fill_poses(records)), _system_status(system_status))
