"""b-CAP VARIANTs: the ``VT`` type codes, :class:`Variant` and its wire codec with the
decoder's caps.

A VARIANT on the wire is ``u16 vt | u32 count | data`` (little-endian; DENSO WAVE's b-CAP
communication specification).

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
"""

from __future__ import annotations

import datetime as _dt
import decimal
import struct
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

from .hresult import invalid_packet as _bad

# Decoder caps. b-CAP itself bounds a VARIANT only by its packet; tmscal's limits keep a
# hostile or corrupt peer from making the decoder spend unbounded time or memory. Real traffic
# is far below them (replies carry 0 or 1 value, poses 7 numbers). Exceeding one raises
# ProtocolError. The packet-level caps are in ``packet.py``.
#: Most elements in one typed array (numbers, BOOL, BSTR; UI1 arrays are bounded by the
#: packet size alone).
MAX_ARRAY_ELEMENTS = 1 << 20
#: Most VARIANTs (arguments, VARIANT-array elements and nested VARIANTs) in one packet.
MAX_VARIANTS = 1 << 18
#: Deepest nesting of VARIANT arrays the decoder follows.
MAX_NESTING = 32


class VT(IntEnum):
    """VARIANT type codes (``vt``); ``ARRAY`` is the flag or-ed onto an element type."""

    EMPTY = 0
    NULL = 1
    I2 = 2
    I4 = 3
    R4 = 4
    R8 = 5
    CY = 6
    DATE = 7
    BSTR = 8
    ERROR = 10
    BOOL = 11
    VARIANT = 12
    UI1 = 17
    UI2 = 18
    UI4 = 19
    I8 = 20
    UI8 = 21
    ARRAY = 0x2000


# The same codes under the names DENSO's documentation and clients use (``VT_R8 | VT_ARRAY``).
VT_EMPTY, VT_NULL, VT_I2, VT_I4 = VT.EMPTY, VT.NULL, VT.I2, VT.I4
VT_R4, VT_R8, VT_CY, VT_DATE, VT_BSTR = VT.R4, VT.R8, VT.CY, VT.DATE, VT.BSTR
VT_ERROR, VT_BOOL, VT_VARIANT = VT.ERROR, VT.BOOL, VT.VARIANT
VT_UI1, VT_UI2, VT_UI4, VT_I8, VT_UI8 = VT.UI1, VT.UI2, VT.UI4, VT.I8, VT.UI8
VT_ARRAY = VT.ARRAY

#: Name of every scalar type code, e.g. ``{5: "R8", …}``.
VT_NAMES: dict[int, str] = {int(t): t.name for t in VT if t is not VT.ARRAY}

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
#: Numeric scalar types (the element types of a numeric typed array).
NUMERIC_VTS = frozenset({VT_I2, VT_I4, VT_R4, VT_R8, VT_UI1, VT_UI2, VT_UI4, VT_I8, VT_UI8})

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

class VariantReader:
    """Decoding state over one buffer: ``end`` bounds every read (no slicing copies), and
    ``budget`` counts the VARIANTs still allowed (:data:`MAX_VARIANTS`). The packet decoder
    keeps one reader over a packet, moving ``end`` to each argument's end."""

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
        """The VARIANT at ``pos`` and the offset after it."""
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
        if vt & VT_ARRAY:
            value, pos = self.array(vt, count, pos, depth)
        elif count != 1:
            raise _bad(f"scalar {vt_name(vt)} with count {count} (expected 1)")
        else:
            value, pos = self.scalar(vt, pos, depth)
        return Variant(vt, value), pos

    def scalar(self, vt: int, pos: int, depth: int) -> tuple[Any, int]:
        if vt == VT_BSTR:
            return self.bstr(pos)
        if vt == VT_VARIANT:
            return self.variant(pos, depth + 1)
        if vt in _FIXED:
            return self.fixed(vt, pos)
        raise _bad(f"unsupported VARIANT type {vt_name(vt)} (0x{vt:04X})")

    def array(self, vt: int, count: int, pos: int, depth: int) -> tuple[Any, int]:
        evt = vt & ~VT_ARRAY
        if evt == VT_UI1:  # raw bytes: bounded by the packet size alone
            self.need(pos, count, "UI1 array")
            return bytes(self.buf[pos:pos + count]), pos + count
        if evt not in _ARRAY_ELEMENTS:
            raise _bad(f"unsupported array type {vt_name(vt)} (0x{vt:04X})")
        if evt == VT_VARIANT:
            if count > self.budget:
                raise _bad(f"VARIANT array of {count} elements: more than {MAX_VARIANTS} "
                           "VARIANTs in one packet")
            self.need(pos, 6 * count, "VARIANT array")  # every element is at least 6 bytes
            return self.repeat(count, pos, lambda p: self.variant(p, depth + 1))
        if evt == VT_BSTR:
            self.need(pos, 4 * count, "BSTR array")  # every element is at least 4 bytes
            self.cap(vt, count)
            return self.repeat(count, pos, self.bstr)
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
        return vals, pos + size * count

    @staticmethod
    def repeat(count: int, pos: int,
               read: Callable[[int], tuple[Any, int]]) -> tuple[list[Any], int]:
        """``count`` items read one after the other from ``pos``."""
        items = []
        for _ in range(count):
            item, pos = read(pos)
            items.append(item)
        return items, pos


def decode_variant(buf: bytes, pos: int = 0, depth: int = 0) -> tuple[Variant, int]:
    """Decode one VARIANT at ``buf[pos:]``; returns (Variant, next offset). Raises
    ``ProtocolError`` (code E_INVALIDPACKET) for truncated or unsupported data and beyond the
    decoder's caps (:data:`MAX_NESTING`, :data:`MAX_ARRAY_ELEMENTS`, :data:`MAX_VARIANTS`)."""
    r = VariantReader(buf, len(buf))
    if pos < 0:
        raise _bad(f"negative offset {pos}")
    return r.variant(pos, depth)


__all__ = [
    "VT", "Variant", "EMPTY", "to_variant", "encode_variant", "decode_variant",
    "VariantReader", "vt_name", "date_from_datetime", "datetime_from_date", "VT_NAMES",
    "NUMERIC_VTS", "MAX_ARRAY_ELEMENTS", "MAX_VARIANTS", "MAX_NESTING",
    "VT_EMPTY", "VT_NULL", "VT_I2", "VT_I4", "VT_R4", "VT_R8", "VT_CY", "VT_DATE", "VT_BSTR",
    "VT_ERROR", "VT_BOOL", "VT_VARIANT", "VT_UI1", "VT_UI2", "VT_UI4", "VT_I8", "VT_UI8",
    "VT_ARRAY",
]
