"""What the numbers on the NDI Combined API wire mean: ``ERRORxx`` / ``WARNINGxx`` codes,
the status words of TX / BX / PHSR / PHINF replies as ``enum.IntFlag`` s, the TX / BX reply
options, the BX handle status byte and the COMM baud-rate codes. Values from NDI's Polaris
Application Program Interface Guide (Combined API); the bit values agree with ndicapi's.

The flags are ints: ``PortStatus(0x31) == 0x31`` and ``status & PortStatus.ENABLED`` work on a
raw word too. Bits the guide reserves are kept (``PortStatus(0x10000)`` does not raise).
"""

from __future__ import annotations

import enum

__all__ = [
    "DEVICE", "ERROR_TEXTS", "WARNING_TEXTS", "error_text", "warning_text", "ErrorCode",
    "PortStatus",
    "SystemStatus", "HandleStatus", "ToolInfoStatus", "ReplyOption", "BxStatus",
    "PORT_HEALTHY", "flag_names", "BAUD_CODES", "BAUD_FROM_CODE",
]

#: ``device`` of the errors the codec raises.
DEVICE = "ndi"

#: ``ERRORxx`` code -> meaning (NDI Combined API). The texts follow NDI's Polaris API guide as
#: ndicapi's ``ndiErrorString`` gives them (PlusToolkit/ndicapi; 0x29 and 0x34-0x39 from its
#: newer table, see docs/devices.md).
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
    0x29: "main processor firmware corrupt",
    0x2A: "no memory available (heap full)",
    0x2B: "port handle not allocated",
    0x2C: "port handle unoccupied",
    0x2D: "no more port handles available",
    0x2E: "incompatible firmware versions",
    0x2F: "invalid port description",
    0x30: "requested port already has a handle",
    0x32: "invalid operation for this port handle",
    0x33: "feature unavailable",
    0x34: "user parameter does not exist",
    0x35: "invalid value type (e.g. a string instead of an integer)",
    0x36: "user parameter value out of the valid range",
    0x37: "user parameter array index out of the valid range",
    0x38: "user parameter size is incorrect",
    0x39: "permission denied (read-only file or user parameter, or a master-mode command "
          "from a monitor-mode connection)",
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


class ErrorCode(enum.IntEnum):
    """Names for the ``ERRORxx`` codes the driver and the mock act on (meanings in
    :data:`ERROR_TEXTS`)."""

    INVALID_COMMAND = 0x01
    COMMAND_TOO_LONG = 0x02
    BAD_COMMAND_CRC = 0x04
    BAD_COMM_PARAMETERS = 0x06
    WRONG_PARAMETER_COUNT = 0x07
    INVALID_PORT_HANDLE = 0x08
    INVALID_PRIORITY = 0x09
    INVALID_MODE = 0x0C
    NO_TOOL = 0x0D
    HANDLE_NOT_INITIALIZED = 0x0E
    HANDLE_NOT_ENABLED = 0x0F
    SYSTEM_NOT_INITIALIZED = 0x10
    PARAMETER_OUT_OF_RANGE = 0x23
    HANDLE_NOT_ALLOCATED = 0x2B
    NO_MORE_HANDLES = 0x2D


class PortStatus(enum.IntFlag):
    """Port status word of a tool in a TX reply (8 hex digits) or a BX reply (uint32)."""

    OCCUPIED = 0x0001
    SWITCH_1 = 0x0002
    SWITCH_2 = 0x0004
    SWITCH_3 = 0x0008
    INITIALIZED = 0x0010
    ENABLED = 0x0020
    OUT_OF_VOLUME = 0x0040
    PARTIALLY_OUT_OF_VOLUME = 0x0080
    ALGORITHM_LIMITATION = 0x0100
    IR_INTERFERENCE = 0x0200
    PROCESSING_EXCEPTION = 0x1000
    FELL_BEHIND = 0x4000
    DATA_BUFFER_LIMITATION = 0x8000


#: A healthy, enabled tool.
PORT_HEALTHY = PortStatus.OCCUPIED | PortStatus.INITIALIZED | PortStatus.ENABLED


class SystemStatus(enum.IntFlag):
    """System status word at the end of a TX reply (4 hex digits) or a BX reply (uint16)."""

    COMMUNICATION_SYNC_ERROR = 0x0001
    TOO_MUCH_EXTERNAL_INFRARED = 0x0002
    COMMUNICATION_CRC_ERROR = 0x0004
    RECOVERABLE_COMMUNICATION_EXCEPTION = 0x0008
    HARDWARE_FAILURE = 0x0010
    HARDWARE_CHANGE = 0x0020
    PORT_OCCUPIED = 0x0040
    PORT_UNOCCUPIED = 0x0080
    DIAGNOSTICS_PENDING = 0x0100
    TEMPERATURE_OUT_OF_RANGE = 0x0200


class HandleStatus(enum.IntFlag):
    """Status of a port handle in a PHSR reply (3 hex digits)."""

    OCCUPIED = 0x001
    SWITCH_1 = 0x002
    SWITCH_2 = 0x004
    SWITCH_3 = 0x008
    INITIALIZED = 0x010
    ENABLED = 0x020


class ToolInfoStatus(enum.IntFlag):
    """Port status byte (2 hex digits) at the end of a PHINF tool-information reply."""

    OCCUPIED = 0x01
    SWITCH_1 = 0x02
    SWITCH_2 = 0x04
    SWITCH_3 = 0x08
    INITIALIZED = 0x10
    ENABLED = 0x20
    CURRENT_DETECTED = 0x80


class ReplyOption(enum.IntFlag):
    """The reply option word of TX / BX (4 hex digits)."""

    TRANSFORMS = 0x0001
    TOOL_AND_MARKER_INFO = 0x0002
    SINGLE_STRAY_MARKER = 0x0004
    TOOL_MARKERS = 0x0008
    OUT_OF_VOLUME = 0x0800
    PASSIVE_STRAY_MARKERS = 0x1000


class BxStatus(enum.IntEnum):
    """The handle status byte of a BX record."""

    VALID = 0x01
    MISSING = 0x02
    DISABLED = 0x04


def flag_names(flags: enum.IntFlag) -> str:
    """The set bits of ``flags`` by name, in bit order, unnamed bits in hex:
    ``"IR_INTERFERENCE|0x10000"``; ``"none"`` when no bit is set."""
    value = int(flags)
    cls = type(flags)
    parts = [cls(bit).name or f"0x{bit:X}"
             for bit in (1 << i for i in range(value.bit_length())) if value & bit]
    return "|".join(parts) or "none"


#: COMM baud-rate codes (first COMM parameter).
BAUD_CODES: dict[int, str] = {
    9600: "0", 14400: "1", 19200: "2", 38400: "3", 57600: "4", 115200: "5", 921600: "6",
    1228739: "7", 230400: "A",
}
BAUD_FROM_CODE: dict[str, int] = {v: k for k, v in BAUD_CODES.items()}
