"""The ATI Net F/T Raw Data Transfer (RDT) codec: request packing, record parsing, counts →
newtons and newton-metres. Pure bytes in, bytes out; no socket here.

RDT runs over UDP, port 49152, big-endian (ATI's Net F/T manual, 9620-05-NET FT):

* a **request** is 8 bytes ``>HHI``: the header 0x1234, a command (``STOP`` 0x0000,
  ``START_REALTIME`` 0x0002, ``START_BUFFERED`` 0x0003, ``START_MULTI_UNIT`` 0x0004,
  ``RESET_THRESHOLD_LATCH`` 0x0041, ``SET_SOFTWARE_BIAS`` 0x0042) and a sample count
  (0: stream until stopped);
* a **record** is 36 bytes ``>IIIiiiiii``: ``rdt_sequence`` (1, 2, … within one stream,
  wrapping after 2³²−1), ``ft_sequence`` (the sensor's internal sample number), ``status``
  (0 healthy; bit 31 is the error summary bit) and Fx, Fy, Fz, Tx, Ty, Tz in counts.

Counts become units by dividing by the sensor calibration's counts per force and counts per
torque (``cfgcpf``/``cfgcpt`` in the sensor's ``netftapi2.xml``). 1,000,000 is a common value
but not a universal one, so nothing here assumes it: the config gives both (docs/devices.md).

Every malformed input raises ``ProtocolError`` naming the field (length, header, command),
device "ati".
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from ...errors import ProtocolError

__all__ = ["PORT", "HEADER", "REQUEST", "RECORD", "STOP", "START_REALTIME", "START_BUFFERED",
           "START_MULTI_UNIT", "RESET_THRESHOLD_LATCH", "SET_SOFTWARE_BIAS", "COMMANDS",
           "ERROR_BIT", "Record", "pack_request", "parse_request", "pack_record",
           "parse_record", "describe_status", "wrench_from_counts", "counts_from_wrench",
           "sequence_step"]

#: The Net F/T's RDT UDP port.
PORT = 49152
#: The constant first field of every request.
HEADER = 0x1234
#: Request layout: header, command, sample count.
REQUEST = struct.Struct(">HHI")
#: Record layout: rdt_sequence, ft_sequence, status, Fx, Fy, Fz, Tx, Ty, Tz (counts).
RECORD = struct.Struct(">IIIiiiiii")

STOP = 0x0000
START_REALTIME = 0x0002
START_BUFFERED = 0x0003
START_MULTI_UNIT = 0x0004
RESET_THRESHOLD_LATCH = 0x0041
SET_SOFTWARE_BIAS = 0x0042
#: command code → name, the commands RDT defines
COMMANDS = {STOP: "stop streaming", START_REALTIME: "start real-time streaming",
            START_BUFFERED: "start buffered streaming", START_MULTI_UNIT: "start multi-unit "
            "streaming", RESET_THRESHOLD_LATCH: "reset threshold latch",
            SET_SOFTWARE_BIAS: "set software bias"}
#: the status word's error summary bit (set whenever a bit that reports an error is set)
ERROR_BIT = 31
_INT32 = (-(2**31), 2**31 - 1)


@dataclass(frozen=True)
class Record:
    """One RDT record as sent: sequence numbers, status word, and the six channels in counts
    (Fx, Fy, Fz, Tx, Ty, Tz; sensor frame)."""

    rdt_sequence: int
    ft_sequence: int
    status: int
    counts: tuple[int, int, int, int, int, int]


def pack_request(command: int, count: int = 0) -> bytes:
    """The 8-byte request for ``command`` (a code of ``COMMANDS``) and ``count`` samples
    (0: until stopped). ``ValueError`` for an unknown command or a count outside uint32."""
    if command not in COMMANDS:
        raise ValueError(f"RDT: unknown command 0x{command:04X}")
    if isinstance(count, bool) or not isinstance(count, int) or not 0 <= count < 2**32:
        raise ValueError(f"RDT: sample count must be an integer in 0…2³²−1, got {count!r}")
    return REQUEST.pack(HEADER, command, count)


def parse_request(data: bytes) -> tuple[int, int]:
    """(command, sample count) of a request; ``ProtocolError`` naming the length, the header
    or the command that is wrong."""
    if len(data) != REQUEST.size:
        raise ProtocolError(f"RDT request: length {len(data)} bytes, expected {REQUEST.size}",
                            device="ati")
    header, command, count = REQUEST.unpack(data)
    if header != HEADER:
        raise ProtocolError(f"RDT request: header 0x{header:04X}, expected 0x{HEADER:04X}",
                            device="ati")
    if command not in COMMANDS:
        raise ProtocolError(f"RDT request: unknown command 0x{command:04X}", device="ati")
    return command, count


def pack_record(rec: Record) -> bytes:
    """The 36 bytes of ``rec``; ``ValueError`` for a field outside its wire type."""
    try:
        return RECORD.pack(rec.rdt_sequence, rec.ft_sequence, rec.status, *rec.counts)
    except struct.error as e:
        raise ValueError(f"RDT record {rec}: {e}") from None


def parse_record(data: bytes) -> Record:
    """The record in ``data`` (exactly 36 bytes); ``ProtocolError`` naming the length
    otherwise. Every 36-byte string is a record: the status is judged by the driver."""
    if len(data) != RECORD.size:
        raise ProtocolError(f"RDT record: length {len(data)} bytes, expected {RECORD.size}",
                            device="ati")
    v = RECORD.unpack(data)
    return Record(v[0], v[1], v[2], tuple(v[3:]))  # type: ignore[arg-type]


def describe_status(status: int) -> str:
    """The status word in words: "healthy" for 0, else the hex word and the bits set
    (bit 31 named as the error summary; the other bits by number, as the sensor's manual
    tabulates them per model)."""
    if status == 0:
        return "healthy"
    bits = [b for b in range(32) if status >> b & 1]
    named = [f"bit {b}" + (" (error summary)" if b == ERROR_BIT else "") for b in reversed(bits)]
    return f"status 0x{status:08X}: " + ", ".join(named)


def wrench_from_counts(counts: np.ndarray, counts_per_force: float,
                       counts_per_torque: float) -> np.ndarray:
    """Counts (…, 6) → [Fx, Fy, Fz N, Tx, Ty, Tz N·m] (…, 6), sensor frame, by dividing by
    the calibration's counts per force (per N) and counts per torque (per N·m)."""
    _check_cp(counts_per_force, counts_per_torque)
    c = np.asarray(counts, dtype=np.float64)
    return np.concatenate([c[..., :3] / counts_per_force, c[..., 3:] / counts_per_torque],
                          axis=-1)


def counts_from_wrench(wrench: np.ndarray, counts_per_force: float,
                       counts_per_torque: float) -> np.ndarray:
    """[F N, τ N·m] (…, 6) → int64 counts (…, 6), rounded, clipped to int32 (a saturated
    channel reads its limit, as a saturated gauge does)."""
    _check_cp(counts_per_force, counts_per_torque)
    w = np.asarray(wrench, dtype=np.float64)
    c = np.concatenate([w[..., :3] * counts_per_force, w[..., 3:] * counts_per_torque],
                       axis=-1)
    return np.clip(np.rint(c), *_INT32).astype(np.int64)


def _check_cp(cpf: float, cpt: float) -> None:
    for name, v in (("counts_per_force", cpf), ("counts_per_torque", cpt)):
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) \
                or not v > 0:
            raise ValueError(f"RDT: {name} must be a finite number > 0, got {v!r}")


def sequence_step(previous: int, current: int) -> int:
    """How far ``current`` is after ``previous`` in rdt_sequence order (mod 2³²), as a signed
    step: 1 for the next record, k > 1 when k − 1 records are missing, ≤ 0 for a record that
    is late (reordered) or repeated. Steps beyond ±2³¹ wrap."""
    d = (current - previous) % 2**32
    return d - 2**32 if d >= 2**31 else d
