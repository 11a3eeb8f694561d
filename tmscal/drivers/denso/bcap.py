"""DENSO b-CAP over TCP: packet and VARIANT codec, stream framer, HRESULT table, client.

Wire format (little-endian; DENSO WAVE's b-CAP communication specification)::

    SOH 0x01 | u32 total length (SOH..EOT) | u16 serial | u16 reserved |
    i32 function ID (request) or HRESULT (reply) | u16 argument count |
    per argument: u32 byte length, VARIANT | EOT 0x04

A VARIANT is ``u16 vt | u32 count | data``.

Python value model
------------------
:class:`Variant` ``(vt, value)`` gives exact control over the wire type. ``value`` is

* EMPTY, NULL: ``None``
* I2, I4, I8, UI1, UI2, UI4, UI8: ``int``; ERROR: ``int`` (the HRESULT as unsigned 32 bit)
* R4, R8: ``float``; DATE: ``float`` days since 1899-12-30 (see :func:`date_from_datetime`)
* CY: ``decimal.Decimal`` (a multiple of 0.0001; the wire holds value × 10000 as i64)
* BSTR: ``str``; BOOL: ``bool`` (wire i16, −1 = true)
* VARIANT (scalar 12): a nested :class:`Variant`
* ``vt | VT_ARRAY``: a ``list`` of the element values above; UI1 arrays are ``bytes``;
  VARIANT arrays (0x200C) are a ``list`` of :class:`Variant`.

:func:`to_variant` maps plain Python values the way DENSO's own Python client does
(int → I4, float → R8, str → BSTR, bool → BOOL, None → EMPTY, same-type list → typed array,
mixed list → VARIANT array); :meth:`Variant.to_python` unwraps the other way.

HRESULTs are handled as unsigned 32-bit ints (``0x80010000``), as DENSO writes them.
"""

from __future__ import annotations

import datetime as _dt
import decimal
import logging
import math
import socket
import struct
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from ...errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError, RobotFault

log = logging.getLogger(__name__)

DEFAULT_PORT = 5007
SOH = 0x01
EOT = 0x04
HEADER_SIZE = 15
MIN_PACKET_SIZE = 16
# Decoder caps. b-CAP itself only bounds a packet by its u32 length field and the argument
# count by u16; tmscal's limits keep a hostile or corrupt peer from making the decoder spend
# unbounded time or memory. Real traffic is far below them: requests carry at most 4
# arguments, replies 0 or 1 value, poses 7 numbers. Exceeding one raises ProtocolError.
#: Largest packet the framer and ``decode_packet`` accept (bytes, 16 MiB).
MAX_PACKET_SIZE = 16 * 1024 * 1024
#: Most arguments one packet may carry (the wire field allows 65,535).
MAX_ARGUMENTS = 16384
#: Most elements in one typed array (numbers, BOOL, BSTR; UI1 arrays are bounded by the
#: packet size alone).
MAX_ARRAY_ELEMENTS = 1 << 20
#: Most VARIANTs (arguments, VARIANT-array elements and nested VARIANTs) in one packet.
MAX_VARIANTS = 1 << 18
#: Deepest nesting of VARIANT arrays the decoder follows.
MAX_NESTING = 32

# --- VARIANT types ---------------------------------------------------------------------------

VT_EMPTY = 0
VT_NULL = 1
VT_I2 = 2
VT_I4 = 3
VT_R4 = 4
VT_R8 = 5
VT_CY = 6
VT_DATE = 7
VT_BSTR = 8
VT_ERROR = 10
VT_BOOL = 11
VT_VARIANT = 12
VT_UI1 = 17
VT_UI2 = 18
VT_UI4 = 19
VT_I8 = 20
VT_UI8 = 21
VT_ARRAY = 0x2000

VT_NAMES: dict[int, str] = {
    VT_EMPTY: "EMPTY", VT_NULL: "NULL", VT_I2: "I2", VT_I4: "I4", VT_R4: "R4", VT_R8: "R8",
    VT_CY: "CY", VT_DATE: "DATE", VT_BSTR: "BSTR", VT_ERROR: "ERROR", VT_BOOL: "BOOL",
    VT_VARIANT: "VARIANT", VT_UI1: "UI1", VT_UI2: "UI2", VT_UI4: "UI4", VT_I8: "I8",
    VT_UI8: "UI8",
}

#: Fixed-size scalar types: struct format (little-endian).
_FIXED: dict[int, str] = {
    VT_I2: "<h", VT_I4: "<i", VT_R4: "<f", VT_R8: "<d", VT_CY: "<q", VT_DATE: "<d",
    VT_ERROR: "<I", VT_BOOL: "<h", VT_UI1: "<B", VT_UI2: "<H", VT_UI4: "<I", VT_I8: "<q",
    VT_UI8: "<Q",
}
_INT_RANGES: dict[int, tuple[int, int]] = {
    VT_I2: (-(1 << 15), (1 << 15) - 1), VT_I4: (-(1 << 31), (1 << 31) - 1),
    VT_I8: (-(1 << 63), (1 << 63) - 1), VT_UI1: (0, 255), VT_UI2: (0, 0xFFFF),
    VT_UI4: (0, 0xFFFFFFFF), VT_UI8: (0, (1 << 64) - 1), VT_ERROR: (0, 0xFFFFFFFF),
}
#: Element types allowed in ``vt | VT_ARRAY``.
_ARRAY_ELEMENTS = set(_FIXED) | {VT_BSTR, VT_VARIANT}
_NUMERIC = {VT_I2, VT_I4, VT_R4, VT_R8, VT_UI1, VT_UI2, VT_UI4, VT_I8, VT_UI8}

_DATE_EPOCH = _dt.datetime(1899, 12, 30)


def vt_name(vt: int) -> str:
    """Readable name of a VARIANT type, e.g. ``"R8|ARRAY"``; unknown types as hex."""
    base = VT_NAMES.get(vt & ~VT_ARRAY, f"0x{vt & ~VT_ARRAY:04X}")
    return base + ("|ARRAY" if vt & VT_ARRAY else "")


def date_from_datetime(t: _dt.datetime) -> float:
    """VT_DATE value (days since 1899-12-30, local time, no time zone) of a naive datetime."""
    return (t - _DATE_EPOCH) / _dt.timedelta(days=1)


def datetime_from_date(days: float) -> _dt.datetime:
    """Naive datetime of a VT_DATE value (days since 1899-12-30)."""
    return _DATE_EPOCH + _dt.timedelta(days=days)


@dataclass(frozen=True)
class Variant:
    """One b-CAP VARIANT: the wire type ``vt`` and its Python ``value`` (see module doc)."""

    vt: int
    value: Any = None

    def to_python(self) -> Any:
        """Plain Python value: nested VARIANTs unwrapped, arrays as lists (UI1 as bytes)."""
        if self.vt == VT_VARIANT:
            return self.value.to_python()
        if self.vt == VT_VARIANT | VT_ARRAY:
            return [v.to_python() for v in self.value]
        if self.vt & VT_ARRAY and self.vt != VT_UI1 | VT_ARRAY:
            return list(self.value)
        return self.value

    def __repr__(self) -> str:
        return f"Variant({vt_name(self.vt)}, {self.value!r})"


EMPTY = Variant(VT_EMPTY, None)


def _scalar_vt(x: Any) -> int | None:
    """The scalar vt DENSO's Python client would use for ``x``; None for non-scalars."""
    import numpy as np  # local: numpy scalars are common arguments

    if isinstance(x, bool | np.bool_):
        return VT_BOOL
    if isinstance(x, int | np.integer):
        v = int(x)
        if _INT_RANGES[VT_I4][0] <= v <= _INT_RANGES[VT_I4][1]:
            return VT_I4
        if _INT_RANGES[VT_I8][0] <= v <= _INT_RANGES[VT_I8][1]:
            return VT_I8
        if 0 <= v <= _INT_RANGES[VT_UI8][1]:
            return VT_UI8
        raise ValueError(f"to_variant: integer {v} does not fit in 64 bits")
    if isinstance(x, float | np.floating):
        return VT_R8
    if isinstance(x, str):
        return VT_BSTR
    if isinstance(x, decimal.Decimal):
        return VT_CY
    if isinstance(x, _dt.datetime):
        return VT_DATE
    if x is None:
        return VT_EMPTY
    return None


def _scalar_value(vt: int, x: Any) -> Any:
    if vt == VT_BOOL:
        return bool(x)
    if vt in _INT_RANGES:
        return int(x)
    if vt == VT_R8:
        return float(x)
    if vt == VT_DATE:
        return date_from_datetime(x)
    return x


def to_variant(x: Any) -> Variant:
    """Map a Python value to a :class:`Variant` like DENSO's Python client does.

    int → I4 (I8/UI8 if it does not fit), float → R8, str → BSTR, bool → BOOL, None → EMPTY,
    bytes → UI1 array, Decimal → CY, datetime → DATE, a Variant passes through, a list/tuple
    (or 1-D numpy array) whose elements all map to the same scalar type → that typed array,
    any other list → VARIANT array (0x200C) with each element mapped. An empty list is an
    empty VARIANT array. Raises ``ValueError`` for values it cannot map.
    """
    if isinstance(x, Variant):
        return x
    if isinstance(x, bytes | bytearray | memoryview):
        return Variant(VT_UI1 | VT_ARRAY, bytes(x))
    vt = _scalar_vt(x)
    if vt is not None:
        return Variant(vt, _scalar_value(vt, x))
    if hasattr(x, "tolist") and not isinstance(x, list | tuple):
        x = x.tolist()
        if not isinstance(x, list):
            return to_variant(x)
    if isinstance(x, list | tuple):
        vts = {_element_vt(e) for e in x}
        if len(vts) == 1:
            (evt,) = vts
            if evt is not None and evt in _ARRAY_ELEMENTS:
                return Variant(evt | VT_ARRAY, [_scalar_value(evt, e) for e in x])
        return Variant(VT_VARIANT | VT_ARRAY, [to_variant(e) for e in x])
    raise ValueError(f"to_variant: cannot map {type(x).__name__} value {x!r} to a VARIANT")


def _element_vt(e: Any) -> int | None:
    """Scalar vt of a list element, None for containers (lists, arrays, bytes, Variants)."""
    import numpy as np

    if isinstance(e, list | tuple | Variant | bytes | bytearray | memoryview | np.ndarray):
        return None
    return _scalar_vt(e)


# --- VARIANT encoding --------------------------------------------------------------------------

def _check_int(vt: int, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise ValueError(f"{vt_name(vt)} needs an int, got {type(v).__name__} {v!r}")
    lo, hi = _INT_RANGES[vt]
    if not lo <= v <= hi:
        raise ValueError(f"{vt_name(vt)} value {v} outside [{lo}, {hi}]")
    return v


def _encode_fixed(vt: int, v: Any) -> bytes:
    fmt = _FIXED[vt]
    if vt == VT_BOOL:
        if not isinstance(v, bool):
            raise ValueError(f"BOOL needs a bool, got {type(v).__name__} {v!r}")
        return struct.pack(fmt, -1 if v else 0)
    if vt == VT_CY:
        if not isinstance(v, decimal.Decimal | int):
            raise ValueError(f"CY needs a Decimal, got {type(v).__name__} {v!r}")
        raw = decimal.Decimal(v).scaleb(4)
        if raw != raw.to_integral_value():
            raise ValueError(f"CY value {v} is not a multiple of 0.0001")
        return struct.pack(fmt, _check_int(VT_I8, int(raw)))
    if vt in (VT_R4, VT_R8, VT_DATE):
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise ValueError(f"{vt_name(vt)} needs a float, got {type(v).__name__} {v!r}")
        try:
            return struct.pack(fmt, float(v))
        except OverflowError as e:
            raise ValueError(f"{vt_name(vt)} value {v} out of range") from e
    return struct.pack(fmt, _check_int(vt, v))


def _encode_bstr(s: Any) -> bytes:
    if not isinstance(s, str):
        raise ValueError(f"BSTR needs a str, got {type(s).__name__} {s!r}")
    b = s.encode("utf-16-le", errors="surrogatepass")
    return struct.pack("<I", len(b)) + b


def _encode_data(vt: int, value: Any) -> tuple[int, bytes]:
    """(count, data bytes) of a VARIANT."""
    if vt in (VT_EMPTY, VT_NULL):
        return 1, b""
    if vt == VT_BSTR:
        return 1, _encode_bstr(value)
    if vt == VT_VARIANT:
        if not isinstance(value, Variant):
            raise ValueError(f"VARIANT needs a nested Variant, got {value!r}")
        return 1, encode_variant(value)
    if vt in _FIXED:
        return 1, _encode_fixed(vt, value)
    if vt & VT_ARRAY:
        evt = vt & ~VT_ARRAY
        if evt == VT_UI1:
            if not isinstance(value, bytes | bytearray | memoryview):
                value = bytes(_check_int(VT_UI1, e) for e in value)
            return len(value), bytes(value)
        if evt not in _ARRAY_ELEMENTS:
            raise ValueError(f"arrays of {vt_name(evt)} are not supported")
        items = list(value)
        if evt == VT_BSTR:
            return len(items), b"".join(_encode_bstr(e) for e in items)
        if evt == VT_VARIANT:
            for e in items:
                if not isinstance(e, Variant):
                    raise ValueError(f"VARIANT array elements must be Variant, got {e!r}")
            return len(items), b"".join(encode_variant(e) for e in items)
        return len(items), b"".join(_encode_fixed(evt, e) for e in items)
    raise ValueError(f"unsupported VARIANT type {vt_name(vt)}")


def encode_variant(v: Variant) -> bytes:
    """Wire bytes ``vt | count | data`` of one VARIANT. Raises ``ValueError`` for a value that
    does not fit its type."""
    if not isinstance(v, Variant):
        raise ValueError(f"encode_variant needs a Variant, got {type(v).__name__}")
    count, data = _encode_data(v.vt, v.value)
    return struct.pack("<HI", v.vt, count) + data


# --- VARIANT decoding --------------------------------------------------------------------------

def _bad(msg: str) -> ProtocolError:
    return ProtocolError(f"b-CAP: {msg}", code=E_INVALIDPACKET, text="E_INVALIDPACKET",
                         device="denso")


class _Reader:
    """Decoding state over one buffer: ``end`` bounds every read (no slicing copies), and
    ``budget`` counts the VARIANTs still allowed (:data:`MAX_VARIANTS`)."""

    __slots__ = ("buf", "end", "budget")

    def __init__(self, buf: bytes | memoryview, end: int) -> None:
        self.buf = buf
        self.end = end
        self.budget = MAX_VARIANTS

    def need(self, pos: int, n: int, what: str) -> None:
        if n < 0 or pos + n > self.end:
            raise _bad(f"truncated {what}: need {n} bytes at offset {pos}, "
                       f"only {max(self.end - pos, 0)} left")

    @staticmethod
    def cap(vt: int, count: int) -> None:
        if count > MAX_ARRAY_ELEMENTS:
            raise _bad(f"{vt_name(vt)} of {count} elements (max {MAX_ARRAY_ELEMENTS})")

    def bstr(self, pos: int) -> tuple[str, int]:
        self.need(pos, 4, "BSTR length")
        (n,) = struct.unpack_from("<I", self.buf, pos)
        pos += 4
        self.need(pos, n, "BSTR text")
        if n % 2:
            raise _bad(f"BSTR byte length {n} is odd (UTF-16LE expected)")
        return str(self.buf[pos:pos + n], "utf-16-le", "surrogatepass"), pos + n

    def fixed(self, vt: int, pos: int) -> tuple[Any, int]:
        fmt = _FIXED[vt]
        size = struct.calcsize(fmt)
        self.need(pos, size, vt_name(vt))
        (raw,) = struct.unpack_from(fmt, self.buf, pos)
        if vt == VT_BOOL:
            raw = raw != 0
        elif vt == VT_CY:
            raw = decimal.Decimal(raw).scaleb(-4)
        return raw, pos + size

    def variant(self, pos: int, depth: int) -> tuple[Variant, int]:
        if depth > MAX_NESTING:
            raise _bad(f"VARIANT nesting deeper than {MAX_NESTING}")
        self.budget -= 1
        if self.budget < 0:
            raise _bad(f"more than {MAX_VARIANTS} VARIANTs in one packet")
        self.need(pos, 6, "VARIANT header")
        vt, count = struct.unpack_from("<HI", self.buf, pos)
        pos += 6
        if vt in (VT_EMPTY, VT_NULL):
            if count > 1:
                raise _bad(f"{vt_name(vt)} with count {count}")
            return Variant(vt, None), pos
        if not vt & VT_ARRAY:
            if count != 1:
                raise _bad(f"scalar {vt_name(vt)} with count {count} (expected 1)")
            if vt == VT_BSTR:
                s, pos = self.bstr(pos)
                return Variant(vt, s), pos
            if vt == VT_VARIANT:
                inner, pos = self.variant(pos, depth + 1)
                return Variant(vt, inner), pos
            if vt in _FIXED:
                val, pos = self.fixed(vt, pos)
                return Variant(vt, val), pos
            raise _bad(f"unsupported VARIANT type {vt_name(vt)} (0x{vt:04X})")
        evt = vt & ~VT_ARRAY
        if evt == VT_UI1:  # raw bytes: bounded by the packet size alone
            self.need(pos, count, "UI1 array")
            return Variant(vt, bytes(self.buf[pos:pos + count])), pos + count
        if evt not in _ARRAY_ELEMENTS:
            raise _bad(f"unsupported array type {vt_name(vt)} (0x{vt:04X})")
        if evt == VT_VARIANT:
            if count > self.budget:
                raise _bad(f"VARIANT array of {count} elements: more than {MAX_VARIANTS} "
                           "VARIANTs in one packet")
            self.need(pos, 6 * count, "VARIANT array")  # every element is at least 6 bytes
            items = []
            for _ in range(count):
                e, pos = self.variant(pos, depth + 1)
                items.append(e)
            return Variant(vt, items), pos
        if evt == VT_BSTR:
            self.need(pos, 4 * count, "BSTR array")  # every element is at least 4 bytes
            self.cap(vt, count)
            strs = []
            for _ in range(count):
                s, pos = self.bstr(pos)
                strs.append(s)
            return Variant(vt, strs), pos
        code = _FIXED[evt][1]
        size = struct.calcsize("<" + code)
        self.need(pos, size * count, f"{vt_name(vt)} of {count} elements")
        self.cap(vt, count)
        raw = struct.unpack_from(f"<{count}{code}", self.buf, pos)
        if evt == VT_BOOL:
            vals: list[Any] = [r != 0 for r in raw]
        elif evt == VT_CY:
            vals = [decimal.Decimal(r).scaleb(-4) for r in raw]
        else:
            vals = list(raw)
        return Variant(vt, vals), pos + size * count


def decode_variant(buf: bytes, pos: int = 0, depth: int = 0) -> tuple[Variant, int]:
    """Decode one VARIANT at ``buf[pos:]``; returns (Variant, next offset). Raises
    ``ProtocolError`` (code E_INVALIDPACKET) for truncated or unsupported data and beyond the
    decoder's caps (:data:`MAX_NESTING`, :data:`MAX_ARRAY_ELEMENTS`, :data:`MAX_VARIANTS`)."""
    r = _Reader(buf, len(buf))
    if pos < 0:
        raise _bad(f"negative offset {pos}")
    return r.variant(pos, depth)


# --- functions, HRESULTs -----------------------------------------------------------------------

class Fn(IntEnum):
    """b-CAP function IDs used by tmscal."""

    SERVICE_START = 1
    SERVICE_STOP = 2
    CONTROLLER_CONNECT = 3
    CONTROLLER_DISCONNECT = 4
    CONTROLLER_GETROBOT = 7
    CONTROLLER_GETVARIABLE = 9
    CONTROLLER_GETROBOTNAMES = 13
    CONTROLLER_EXECUTE = 17
    ROBOT_GETVARIABLE = 62
    ROBOT_EXECUTE = 64
    ROBOT_HALT = 70
    ROBOT_MOVE = 72
    ROBOT_SPEED = 74
    ROBOT_RELEASE = 84
    VARIABLE_GETVALUE = 101
    VARIABLE_PUTVALUE = 102
    VARIABLE_RELEASE = 111


FUNCTION_NAMES: dict[int, str] = {
    Fn.SERVICE_START: "Service_Start", Fn.SERVICE_STOP: "Service_Stop",
    Fn.CONTROLLER_CONNECT: "Controller_Connect",
    Fn.CONTROLLER_DISCONNECT: "Controller_Disconnect",
    Fn.CONTROLLER_GETROBOT: "Controller_GetRobot",
    Fn.CONTROLLER_GETVARIABLE: "Controller_GetVariable",
    Fn.CONTROLLER_GETROBOTNAMES: "Controller_GetRobotNames",
    Fn.CONTROLLER_EXECUTE: "Controller_Execute", Fn.ROBOT_GETVARIABLE: "Robot_GetVariable",
    Fn.ROBOT_EXECUTE: "Robot_Execute", Fn.ROBOT_HALT: "Robot_Halt",
    Fn.ROBOT_MOVE: "Robot_Move", Fn.ROBOT_SPEED: "Robot_Speed",
    Fn.ROBOT_RELEASE: "Robot_Release", Fn.VARIABLE_GETVALUE: "Variable_GetValue",
    Fn.VARIABLE_PUTVALUE: "Variable_PutValue", Fn.VARIABLE_RELEASE: "Variable_Release",
}


def function_name(fid: int) -> str:
    """Name of a b-CAP function ID, e.g. ``"Robot_Move"``; unknown IDs as ``"function 99"``."""
    return FUNCTION_NAMES.get(fid, f"function {fid}")


S_OK = 0x00000000
S_EXECUTING = 0x00000900
E_TIMEOUT = 0x80000900
E_NOT_CONNECTED = 0x80000902
E_INVALIDARG = 0x80070057
E_HANDLE = 0x80070006
E_ACCESSDENIED = 0x80070005
E_NOTIMPL = 0x80004001
E_FAIL = 0x80004005
E_BUSY_PROC = 0x809100AA
E_CAO_VARIANT_TYPE_NOSUPPORT = 0x80000203
E_CAO_OBJECT_NOTFOUND = 0x80000204
E_INVALIDPACKET = 0x80010000
E_MOTOR_OFF = 0x81501003
E_EMERGENCY_STOP = 0x83500178
E_SLAVE_MODE = 0x83501032

HRESULT_NAMES: dict[int, str] = {
    S_OK: "S_OK",
    S_EXECUTING: "S_EXECUTING",
    E_TIMEOUT: "E_TIMEOUT",
    E_NOT_CONNECTED: "E_NOT_CONNECTED",
    E_INVALIDARG: "E_INVALIDARG",
    E_HANDLE: "E_HANDLE",
    E_ACCESSDENIED: "E_ACCESSDENIED",
    E_NOTIMPL: "E_NOTIMPL",
    E_FAIL: "E_FAIL",
    E_BUSY_PROC: "E_BUSY_PROC",
    E_CAO_VARIANT_TYPE_NOSUPPORT: "E_CAO_VARIANT_TYPE_NOSUPPORT",
    E_CAO_OBJECT_NOTFOUND: "E_CAO_OBJECT_NOTFOUND",
    E_INVALIDPACKET: "E_INVALIDPACKET",
    E_MOTOR_OFF: "motor off",
    E_EMERGENCY_STOP: "not executable during emergency stop",
    E_SLAVE_MODE: "not allowed in slave mode",
}
for _j in range(1, 9):
    HRESULT_NAMES[0x84204050 + _j] = f"J{_j} speed limit"
    HRESULT_NAMES[0x84204040 + _j] = f"J{_j} acceleration limit"


def hresult_name(code: int) -> str:
    """Name of an HRESULT (unsigned 32-bit int) from the table; unknown codes as
    ``"0x8xxxxxxx"``."""
    code &= 0xFFFFFFFF
    return HRESULT_NAMES.get(code, f"0x{code:08X}")


def is_failure(code: int) -> bool:
    """True for a failure HRESULT (bit 31 set)."""
    return bool(code & 0x80000000)


def next_serial(serial: int) -> int:
    """The serial after ``serial``: +1, wrapping 0xFFFF → 1, never 0."""
    return 1 if serial >= 0xFFFF or serial < 1 else serial + 1


# --- packets -----------------------------------------------------------------------------------

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
    head = struct.pack("<BIHHIH", SOH, total, serial, reserved & 0xFFFF,
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
    soh, total, serial, reserved, code, argc = struct.unpack_from("<BIHHIH", data, 0)
    if total != len(data):
        raise _bad(f"length field {total} disagrees with the {len(data)} bytes received")
    if data[-1] != EOT:
        raise _bad(f"wrong EOT 0x{data[-1]:02X} (expected 0x04)")
    if argc > MAX_ARGUMENTS:
        raise _bad(f"{argc} arguments (max {MAX_ARGUMENTS})")
    end = len(data) - 1
    reader = _Reader(data, end)
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
                       f"{str(e).removeprefix('b-CAP: ')}") from None
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


def finite_numbers(v: Variant | None, what: str, min_len: int, max_len: int) -> list[float]:
    """The values of a reply that must be an array of ``min_len``..``max_len`` finite numbers:
    a numeric typed array (I2, I4, I8, R4, R8, UI1–UI8) or a VARIANT array whose elements are
    numeric scalars. Anything else raises ``ProtocolError`` naming ``what`` and the fault."""
    def bad(msg: str) -> ProtocolError:
        return ProtocolError(f"b-CAP {what}: {msg}", code=E_INVALIDPACKET,
                             text="E_INVALIDPACKET", device="denso")

    if v is None:
        raise bad("the reply carries no value (expected an array of numbers)")
    if v.vt == VT_VARIANT | VT_ARRAY:
        for i, e in enumerate(v.value):
            if e.vt not in _NUMERIC:
                raise bad(f"element {i} is {e!r}, not a number")
        raw = [e.value for e in v.value]
    elif v.vt & VT_ARRAY and (v.vt & ~VT_ARRAY) in _NUMERIC:
        raw = list(v.value)
    else:
        raise bad(f"expected an array of numbers, got {vt_name(v.vt)}")
    if not min_len <= len(raw) <= max_len:
        want = f"{min_len}" if min_len == max_len else f"{min_len} to {max_len}"
        raise bad(f"{len(raw)} values, expected {want}")
    vals = [float(x) for x in raw]
    bad_idx = [i for i, x in enumerate(vals) if not math.isfinite(x)]
    if bad_idx:
        raise bad(f"non-finite value {vals[bad_idx[0]]} at index {bad_idx[0]} in {vals}")
    return vals


# --- client ------------------------------------------------------------------------------------

def _is_controller_error(code: int) -> bool:
    """Controller (robot) errors are 0x81xxxxxx and above; 0x80xxxxxx are library errors."""
    return (code & 0xFFFFFFFF) >= 0x81000000


class BCAPClient:
    """A b-CAP client over TCP: one request at a time, replies matched by serial.

    ``timeout_s`` is the longest wait for a reply after the request was sent or after the
    last S_EXECUTING keep-alive for it (the controller sends those while a command runs when
    Service_Start set ``WDT=<ms>``). Packets with a foreign serial and keep-alives are
    discarded. A failure HRESULT raises ``RobotFault`` for controller errors (≥ 0x81000000,
    and for every failed Robot_Move) and ``DeviceError`` otherwise, with ``code`` the HRESULT
    and ``text`` its name; no reply in time raises ``DeviceTimeout`` naming the function; a
    dropped connection raises ``ConnectionLost``.
    """

    def __init__(self, host: str, port: int = DEFAULT_PORT, timeout_s: float = 5.0) -> None:
        self.host = host
        self.port = int(port)
        self.timeout_s = float(timeout_s)
        self._sock: socket.socket | None = None
        self._framer = PacketFramer()
        self._serial = 0
        self._call_lock = threading.Lock()
        self._send_lock = threading.Lock()

    # lifecycle
    def connect(self) -> BCAPClient:
        """Open the TCP connection (idempotent)."""
        if self._sock is not None:
            return self
        try:
            s = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except OSError as e:
            raise ConnectionLost(f"b-CAP: cannot connect to {self.host}:{self.port}: {e}",
                                 device="denso") from e
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = s
        self._framer = PacketFramer()
        return self

    def close(self) -> None:
        """Close the TCP connection (safe twice). The controller releases every object."""
        s, self._sock = self._sock, None
        if s is not None:
            try:
                s.close()
            except OSError:  # pragma: no cover
                pass

    @property
    def connected(self) -> bool:
        return self._sock is not None

    @property
    def busy(self) -> bool:
        """True while a call waits for its reply (another thread may only ``send_only``)."""
        return self._call_lock.locked()

    def __enter__(self) -> BCAPClient:
        return self.connect()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # core
    def _where(self) -> str:
        return f"{self.host}:{self.port}"

    def _send(self, data: bytes, fname: str) -> None:
        if self._sock is None:
            raise ConnectionLost(f"b-CAP {fname}: not connected to {self._where()}",
                                 device="denso")
        try:
            with self._send_lock:
                self._sock.sendall(data)
        except OSError as e:
            self.close()
            raise ConnectionLost(f"b-CAP {fname}: send to {self._where()} failed: {e}",
                                 device="denso") from e

    def _next_serial(self) -> int:
        self._serial = next_serial(self._serial)
        return self._serial

    def send_only(self, func: int, *args: Any) -> int:
        """Send a request without waiting for its reply (its reply is later discarded as a
        foreign serial). For Robot_Halt while another thread waits on a move. Returns the
        serial."""
        serial = self._next_serial()
        self._send(encode_packet(serial, int(func), args), function_name(func))
        return serial

    def call(self, func: int, *args: Any, timeout_s: float | None = None) -> Variant | None:
        """Send ``func(*args)`` (Variants or Python values) and wait for its reply. Returns
        the reply's value (a Variant) or None when the reply carries none."""
        fname = function_name(func)
        with self._call_lock:
            serial = self._next_serial()
            self._send(encode_packet(serial, int(func), args), fname)
            reply = self._wait_reply(serial, fname,
                                     self.timeout_s if timeout_s is None else timeout_s)
        if reply.failed:
            name = hresult_name(reply.code)
            cls = RobotFault if (_is_controller_error(reply.code)
                                 or func == Fn.ROBOT_MOVE) else DeviceError
            raise cls(f"b-CAP {fname} failed: 0x{reply.code:08X} ({name})", code=reply.code,
                      text=name, device="denso")
        return reply.args[0] if reply.args else None

    def _wait_reply(self, serial: int, fname: str, timeout_s: float) -> Packet:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                pkt = self._framer.next_packet()
            except ProtocolError as e:
                raise ProtocolError(f"b-CAP {fname}: {e}", code=E_INVALIDPACKET,
                                    text="E_INVALIDPACKET", device="denso") from e
            if pkt is not None:
                if pkt.serial != serial:
                    log.debug("b-CAP %s: discarding packet with foreign serial %d "
                              "(expected %d)", fname, pkt.serial, serial)
                    continue
                if pkt.code == S_EXECUTING:
                    log.debug("b-CAP %s: S_EXECUTING keep-alive", fname)
                    deadline = time.monotonic() + timeout_s
                    continue
                return pkt
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(f"b-CAP {fname}: no reply from {self._where()} within "
                                    f"{timeout_s:.1f} s", code=E_TIMEOUT, text="E_TIMEOUT",
                                    device="denso")
            sock = self._sock
            if sock is None:
                raise ConnectionLost(f"b-CAP {fname}: connection to {self._where()} closed",
                                     device="denso")
            try:
                sock.settimeout(min(remaining, 1.0))
                data = sock.recv(65536)
            except TimeoutError:
                continue
            except OSError as e:
                self.close()
                raise ConnectionLost(f"b-CAP {fname}: connection to {self._where()} "
                                     f"dropped: {e}", device="denso") from e
            if not data:
                self.close()
                raise ConnectionLost(f"b-CAP {fname}: {self._where()} closed the connection "
                                     "while a reply was awaited", device="denso")
            self._framer.feed(data)

    def _value(self, func: int, *args: Any, timeout_s: float | None = None) -> Any:
        v = self.call(func, *args, timeout_s=timeout_s)
        return None if v is None else v.to_python()

    def _handle(self, func: int, *args: Any) -> int:
        v = self.call(func, *args)
        if v is None or v.vt not in _NUMERIC or isinstance(v.value, float):
            raise ProtocolError(f"b-CAP {function_name(func)}: expected a handle (I4), got "
                                f"{v!r}", code=E_INVALIDPACKET, text="E_INVALIDPACKET",
                                device="denso")
        return int(v.value)

    # functions
    def service_start(self, option: str = "") -> None:
        """Service_Start; ``option`` e.g. ``",WDT=400,InvokeTimeout=180000"``."""
        self.call(Fn.SERVICE_START, option)

    def service_stop(self) -> None:
        self.call(Fn.SERVICE_STOP)

    def controller_connect(self, name: str = "", provider: str = "CaoProv.DENSO.VRC",
                           machine: str = "localhost", option: str = "") -> int:
        """Controller_Connect → controller handle."""
        return self._handle(Fn.CONTROLLER_CONNECT, name, provider, machine, option)

    def controller_disconnect(self, handle: int) -> None:
        self.call(Fn.CONTROLLER_DISCONNECT, Variant(VT_I4, handle))

    def controller_get_robot(self, handle: int, name: str = "Arm", option: str = "") -> int:
        """Controller_GetRobot → robot handle."""
        return self._handle(Fn.CONTROLLER_GETROBOT, Variant(VT_I4, handle), name, option)

    def controller_get_variable(self, handle: int, name: str, option: str = "") -> int:
        """Controller_GetVariable → variable handle."""
        return self._handle(Fn.CONTROLLER_GETVARIABLE, Variant(VT_I4, handle), name, option)

    def controller_get_robot_names(self, handle: int, option: str = "") -> list[str]:
        return self._value(Fn.CONTROLLER_GETROBOTNAMES, Variant(VT_I4, handle), option) or []

    def controller_execute(self, handle: int, command: str, param: Any = None) -> Any:
        """Controller_Execute → plain Python value (None for EMPTY)."""
        return self._value(Fn.CONTROLLER_EXECUTE, Variant(VT_I4, handle), command, param)

    def robot_execute(self, handle: int, command: str, param: Any = None,
                      timeout_s: float | None = None) -> Any:
        """Robot_Execute (TakeArm, GiveArm, Motor, ExtSpeed, CurPos, CurJnt …) → plain Python
        value (None for EMPTY)."""
        return self._value(Fn.ROBOT_EXECUTE, Variant(VT_I4, handle), command, param,
                           timeout_s=timeout_s)

    def take_arm(self, handle: int, group: int = 0, keep: int = 0) -> None:
        self.robot_execute(handle, "TakeArm", [group, keep])

    def give_arm(self, handle: int) -> None:
        self.robot_execute(handle, "GiveArm", None)

    def motor(self, handle: int, on: bool) -> None:
        """Motor on/off; waits until the controller confirms (``[state, 0]``)."""
        self.robot_execute(handle, "Motor", [1 if on else 0, 0])

    def ext_speed(self, handle: int, speed: float, accel: float, decel: float) -> None:
        """ExtSpeed in percent."""
        self.robot_execute(handle, "ExtSpeed", [float(speed), float(accel), float(decel)])

    def cur_pos(self, handle: int) -> list[float]:
        """CurPos: P-type [x, y, z (mm), rx, ry, rz (deg)] plus fig when the controller sends
        it (6 or 7 finite numbers). A reply that is not an array of numbers (a numeric typed
        array such as VT_R8|VT_ARRAY, or a VARIANT array of numbers), has another length, or
        holds NaN/±inf raises ``ProtocolError`` naming CurPos and the fault."""
        v = self.call(Fn.ROBOT_EXECUTE, Variant(VT_I4, handle), "CurPos", None)
        return finite_numbers(v, "Robot_Execute CurPos", 6, 7)

    def cur_jnt(self, handle: int) -> list[float]:
        """CurJnt: joint angles in degrees (1 to 32 finite numbers; otherwise
        ``ProtocolError`` as for :meth:`cur_pos`)."""
        v = self.call(Fn.ROBOT_EXECUTE, Variant(VT_I4, handle), "CurJnt", None)
        return finite_numbers(v, "Robot_Execute CurJnt", 1, 32)

    def robot_move(self, handle: int, comp: int, pose: Any, option: str = "",
                   timeout_s: float | None = None) -> None:
        """Robot_Move; comp 1 = MOVE P, 2 = MOVE L; ``pose`` a text like ``"@P P(…)"`` or a
        VARIANT array ``[[x, y, z, rx, ry, rz, fig], "P", "@P"]`` (mm, deg). Without NEXT in
        ``option`` the reply comes when the motion is done. Failures raise ``RobotFault``."""
        self.call(Fn.ROBOT_MOVE, Variant(VT_I4, handle), Variant(VT_I4, comp), pose, option,
                  timeout_s=timeout_s)

    def robot_halt(self, handle: int, option: str = "", wait: bool = True) -> None:
        """Robot_Halt; ``wait=False`` sends it without waiting (usable while another thread
        waits on a move over this connection)."""
        if wait:
            self.call(Fn.ROBOT_HALT, Variant(VT_I4, handle), option)
        else:
            self.send_only(Fn.ROBOT_HALT, Variant(VT_I4, handle), option)

    def robot_speed(self, handle: int, axis: int, speed: float) -> None:
        self.call(Fn.ROBOT_SPEED, Variant(VT_I4, handle), Variant(VT_I4, axis),
                  Variant(VT_R4, float(speed)))

    def robot_get_variable(self, handle: int, name: str, option: str = "") -> int:
        """Robot_GetVariable → variable handle (e.g. ``"@CURRENT_POSITION"``)."""
        return self._handle(Fn.ROBOT_GETVARIABLE, Variant(VT_I4, handle), name, option)

    def robot_release(self, handle: int) -> None:
        self.call(Fn.ROBOT_RELEASE, Variant(VT_I4, handle))

    def variable_get_value(self, handle: int) -> Any:
        """Variable_GetValue → plain Python value."""
        return self._value(Fn.VARIABLE_GETVALUE, Variant(VT_I4, handle))

    def variable_put_value(self, handle: int, value: Any) -> None:
        self.call(Fn.VARIABLE_PUTVALUE, Variant(VT_I4, handle), value)

    def variable_release(self, handle: int) -> None:
        self.call(Fn.VARIABLE_RELEASE, Variant(VT_I4, handle))


__all__ = [
    "BCAPClient", "Packet", "PacketFramer", "Variant", "EMPTY", "Fn", "to_variant",
    "encode_variant", "decode_variant", "encode_packet", "decode_packet", "hresult_name",
    "function_name", "vt_name", "next_serial", "MAX_PACKET_SIZE", "MAX_ARGUMENTS",
    "MAX_ARRAY_ELEMENTS", "MAX_VARIANTS", "MAX_NESTING", "is_failure", "date_from_datetime",
    "datetime_from_date", "finite_numbers", "HRESULT_NAMES", "FUNCTION_NAMES", "VT_NAMES",
    "DEFAULT_PORT",
]
