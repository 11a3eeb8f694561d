"""b-CAP HRESULTs: the codes tmscal names, their names, and the one way a malformed packet
becomes an error.

HRESULTs are handled as unsigned 32-bit ints (``0x80010000``), as DENSO writes them. Bit 31
marks a failure; 0x80xxxxxx are b-CAP / library errors, 0x81xxxxxx and above are the
controller's own (robot) errors (DENSO WAVE's b-CAP communication specification and the RC8
error code tables).
"""

from __future__ import annotations

from ...errors import ProtocolError

#: The ``device`` every b-CAP error carries.
DEVICE = "denso"

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

#: Names of the codes above: the constant's own name, or the controller's message for
#: controller errors.
HRESULT_NAMES: dict[int, str] = {
    code: name for name, code in globals().items()
    if name[:2] in ("S_", "E_") and isinstance(code, int)
}
HRESULT_NAMES.update({
    E_MOTOR_OFF: "motor off",
    E_EMERGENCY_STOP: "not executable during emergency stop",
    E_SLAVE_MODE: "not allowed in slave mode",
})
for _j in range(1, 9):
    HRESULT_NAMES[0x84204050 + _j] = f"J{_j} speed limit"
    HRESULT_NAMES[0x84204040 + _j] = f"J{_j} acceleration limit"
del _j


def hresult_name(code: int) -> str:
    """Name of an HRESULT (unsigned 32-bit int) from the table; unknown codes as
    ``"0x8xxxxxxx"``."""
    code &= 0xFFFFFFFF
    return HRESULT_NAMES.get(code, f"0x{code:08X}")


def is_failure(code: int) -> bool:
    """True for a failure HRESULT (bit 31 set)."""
    return bool(code & 0x80000000)


def is_controller_error(code: int) -> bool:
    """Controller (robot) errors are 0x81xxxxxx and above; 0x80xxxxxx are library errors."""
    return (code & 0xFFFFFFFF) >= 0x81000000


def invalid_packet(msg: str, what: str = "b-CAP") -> ProtocolError:
    """The error for bytes that do not decode: ``"<what>: <msg>"`` with code
    E_INVALIDPACKET."""
    return ProtocolError(f"{what}: {msg}", code=E_INVALIDPACKET, text="E_INVALIDPACKET",
                         device=DEVICE)


__all__ = [
    "DEVICE", "HRESULT_NAMES", "hresult_name", "is_failure", "is_controller_error",
    "invalid_packet", "S_OK", "S_EXECUTING", "E_TIMEOUT", "E_NOT_CONNECTED", "E_INVALIDARG",
    "E_HANDLE", "E_ACCESSDENIED", "E_NOTIMPL", "E_FAIL", "E_BUSY_PROC",
    "E_CAO_VARIANT_TYPE_NOSUPPORT", "E_CAO_OBJECT_NOTFOUND", "E_INVALIDPACKET", "E_MOTOR_OFF",
    "E_EMERGENCY_STOP", "E_SLAVE_MODE",
]
