"""Reading the arguments of a b-CAP request in the DENSO mock: numbers, texts, options,
percentages and poses. A value the mock cannot use raises :class:`Refusal` with the HRESULT
to answer (E_INVALIDARG unless said otherwise)."""

from __future__ import annotations

import math
import re

import numpy as np

from ...drivers.denso.hresult import E_INVALIDARG, E_NOTIMPL
from ...drivers.denso.variant import (
    NUMERIC_VTS,
    VT_ARRAY,
    VT_BSTR,
    VT_EMPTY,
    VT_NULL,
    VT_VARIANT,
    Variant,
)

#: Range of every speed / acceleration percentage (SPEED, ACCEL, DECEL, ExtSpeed).
PCT_MIN, PCT_MAX = 0.01, 100.0

_P_TEXT = re.compile(r"^\s*(?:@\w+\s+)?P\s*\(([^()]*)\)\s*$", re.IGNORECASE)
_PASS_TEXT = re.compile(r"^\s*(@\w+)\s", re.IGNORECASE)
_PASS = re.compile(r"^@(0|P|E|\d+(\.\d*)?)$", re.IGNORECASE)


class Refusal(Exception):
    """A request the mock answers with the error HRESULT ``code``; the message says why."""

    def __init__(self, code: int, why: str) -> None:
        super().__init__(why)
        self.code = code


def number(v: Variant, what: str) -> float:
    """A numeric scalar as float."""
    if v.vt not in NUMERIC_VTS:
        raise Refusal(E_INVALIDARG, f"{what}: expected a number, got {v!r}")
    return float(v.value)


def percent(x: float, what: str) -> float:
    """A speed / acceleration percentage: finite and in [PCT_MIN, PCT_MAX]."""
    if not (math.isfinite(x) and PCT_MIN <= x <= PCT_MAX):
        raise Refusal(E_INVALIDARG, f"{what} {x!r} outside [{PCT_MIN}, {PCT_MAX}] %")
    return x


def option_percent(opts: dict[str, str], keys: tuple[str, ...], what: str,
                   option: str) -> float | None:
    """The percentage of the first of ``keys`` present in a move option, else None."""
    for k in keys:
        if k in opts:
            try:
                x = float(opts[k])
            except ValueError:
                raise Refusal(E_INVALIDARG, f"bad {what} in option {option!r}") from None
            return percent(x, what)
    return None


def numbers(v: Variant, what: str) -> list[float]:
    """Numbers from a numeric scalar, a numeric array or a VARIANT array of numbers;
    EMPTY → []."""
    if v.vt in (VT_EMPTY, VT_NULL):
        return []
    if v.vt in NUMERIC_VTS:
        return [float(v.value)]
    if v.vt & VT_ARRAY and (v.vt & ~VT_ARRAY) in NUMERIC_VTS:
        return [float(x) for x in v.value]
    if v.vt == VT_VARIANT | VT_ARRAY:
        return [number(e, what) for e in v.value]
    raise Refusal(E_INVALIDARG, f"{what}: expected numbers, got {v!r}")


def text(v: Variant, what: str) -> str:
    """A BSTR's text; EMPTY / NULL → ``""``."""
    if v.vt in (VT_EMPTY, VT_NULL):
        return ""
    if v.vt != VT_BSTR:
        raise Refusal(E_INVALIDARG, f"{what}: expected a BSTR, got {v!r}")
    return v.value


def options(option: str) -> dict[str, str]:
    """A b-CAP option string ``"KEY=value, FLAG"`` as ``{"KEY": "value", "FLAG": ""}``
    (keys upper case)."""
    out: dict[str, str] = {}
    for part in option.split(","):
        part = part.strip()
        if part:
            k, _, val = part.partition("=")
            out[k.strip().upper()] = val.strip()
    return out


def pose(v: Variant) -> list[float]:
    """P-type [x, y, z (mm), rx, ry, rz (deg), fig] from a pose argument of Robot_Move: the
    text ``"@P P(x, y, z, rx, ry, rz[, fig])"``, a VARIANT array ``[[x, …, fig], "P", "@P"]``
    or numbers; a missing fig is −1."""
    if v.vt == VT_BSTR:
        m = _P_TEXT.match(v.value)
        if not m:
            raise Refusal(E_INVALIDARG, f"pose text {v.value!r} is not '@P P(x, y, z, rx, "
                                        "ry, rz, fig)' (J/T poses are not supported)")
        try:
            vals = [float(s) for s in m.group(1).split(",")]
        except ValueError:
            raise Refusal(E_INVALIDARG, f"pose text {v.value!r} has a non-number") from None
    elif v.vt == VT_VARIANT | VT_ARRAY and v.value and v.value[0].vt & VT_ARRAY:
        items = v.value
        if len(items) > 1 and text(items[1], "pose type").upper() not in ("P", ""):
            raise Refusal(E_NOTIMPL, f"pose type {items[1].value!r} not supported (only P)")
        vals = numbers(items[0], "pose values")
    else:
        vals = numbers(v, "pose")
    if len(vals) == 6:
        vals.append(-1.0)
    if len(vals) != 7 or not np.isfinite(vals).all():
        raise Refusal(E_INVALIDARG, f"pose needs 6 or 7 finite values, got {vals}")
    return vals


def pass_mode(v: Variant) -> str:
    """The path-end option of a Robot_Move pose, upper case: ``"@E"`` (wait until the arm has
    reached the target and settled), ``"@P"`` (until the command reached it), ``"@0"`` or
    ``"@<n>"`` (pass motion); from the text prefix (``"@E P(…)"``) or the third element of a
    VARIANT array pose. Missing → ``"@0"`` (the controller's default, pass motion); anything
    else → ``Refusal(E_INVALIDARG)``."""
    mode = ""
    if v.vt == VT_BSTR:
        m = _PASS_TEXT.match(v.value)
        mode = m.group(1) if m else ""
    elif v.vt == VT_VARIANT | VT_ARRAY and len(v.value) > 2:
        mode = text(v.value[2], "pose pass option").strip()
    if not mode:
        return "@0"
    if not _PASS.match(mode):
        raise Refusal(E_INVALIDARG, f"pose pass option {mode!r} is not @0, @P, @E or @<n>")
    return mode.upper()
