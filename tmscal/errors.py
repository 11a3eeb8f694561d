"""The tmscal exception tree (one root; device codes ride along).

::

    TmscalError
    ├── ConfigError        invalid or unreadable config (names file and key)
    │   └── MissingExtraError  a driver or mock needs an optional extra that is not installed
    ├── SessionError       malformed or unreadable session file (names file and line)
    ├── CalibrationError   a solve that cannot be done (too few poses, degenerate data)
    ├── SafetyError        a pose or speed outside the configured envelope; nothing was sent
    └── DeviceError        a device said no (carries ``device``, ``code`` and ``text``)
        ├── ProtocolError  malformed, torn or corrupt bytes on the wire
        ├── DeviceTimeout  no (complete) reply in time; also a ``TimeoutError``
        ├── ConnectionLost the link dropped
        └── RobotFault     protective / emergency stop, motor off, unreachable pose

``ValueError`` is used only for bad arguments to pure functions (shapes, NaN).

``str(DeviceError)`` is the one line a user sees: ``"<device>: <message> [<code> (<name>)]"``,
where the device prefix, the code and its name are each added only when given and not already
in the message (so ``"b-CAP Robot_Move failed: 0x83500178 (not executable during emergency
stop)"`` raised with ``device="denso"`` reads ``"denso: b-CAP Robot_Move failed: …"`` once).
"""

from __future__ import annotations

import re


class TmscalError(Exception):
    """Root of every error tmscal raises on purpose."""


class ConfigError(TmscalError):
    """A config file is unreadable or invalid; the message names the file and the key."""


class MissingExtraError(ConfigError):
    """A driver or mock needs an optional extra that is not installed. ``extra`` is the extra's
    name; the message says what needs it and the ``pip install 'tmscal[extra]'`` line."""

    def __init__(self, what: str, extra: str, reason: str = "") -> None:
        why = f" ({reason})" if reason else ""
        super().__init__(f"{what} needs the optional extra '{extra}'{why}: "
                         f"pip install 'tmscal[{extra}]'")
        self.what = what
        self.extra = extra
        self.reason = reason

    # picklable with its fields (multiprocessing, logging handlers)
    def __reduce__(self) -> tuple[type, tuple[object, ...]]:
        return (type(self), (self.what, self.extra, self.reason))


class SessionError(TmscalError):
    """A session file is unreadable or malformed; the message names the file and the line."""


class CalibrationError(TmscalError):
    """The data cannot give a calibration (too few poses, no rotation diversity, …)."""


class SafetyError(TmscalError):
    """A commanded pose or speed is outside the configured safety envelope; nothing was sent."""


class DeviceError(TmscalError):
    """A device reported an error. ``device`` names it ("ndi", "denso", "ur"); ``code`` is the
    device's own code (NDI ``ERRORxx`` code, b-CAP HRESULT, UR safety mode …) and ``text`` the
    code's name or meaning, where known. ``message`` is the text as raised; ``str()`` adds the
    device, code and name that the message does not already carry (see the module docstring).
    """

    def __init__(self, message: str, code: int | str | None = None, text: str | None = None,
                 device: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.code = code
        self.text = text
        self.device = device

    def __str__(self) -> str:
        msg = self.message
        extra = []
        if self.code is not None and not _mentions_code(msg, self.code):
            extra.append(format_code(self.code))
        if self.text and self.text not in msg:
            extra.append(f"({self.text})")
        if extra:
            msg = f"{msg} [{' '.join(extra)}]"
        if self.device and not re.match(rf"{re.escape(self.device)}\b", msg, re.IGNORECASE):
            msg = f"{self.device}: {msg}"
        return msg

    def __reduce__(self) -> tuple[type, tuple[object, ...]]:  # picklable with its fields
        return (type(self), (self.message, self.code, self.text, self.device))


def format_code(code: int | str) -> str:
    """A device code as messages show it: a 32-bit HRESULT-sized int as ``0x83500178``, a
    small int as ``code 3``, a string as it is."""
    if isinstance(code, bool) or not isinstance(code, int):
        return str(code)
    return f"0x{code & 0xFFFFFFFF:08X}" if abs(code) > 0xFFFF else f"code {code}"


def _mentions_code(message: str, code: int | str) -> bool:
    """True when ``message`` already names ``code``: as written by ``format_code``, as hex after
    ``0x`` or NDI's ``ERROR`` (``ERROR0C``), or as a number after the word "code"."""
    if isinstance(code, bool) or not isinstance(code, int):
        return str(code) in message
    hexa = f"{code & 0xFFFFFFFF:X}" if code < 0 else f"{code:X}"
    pat = rf"(?:0x|ERROR)0*{hexa}(?![0-9A-F])|code\s+(?:0x)?0*(?:{code}|{hexa})(?![0-9A-F])"
    return re.search(pat, message, re.IGNORECASE) is not None


class ProtocolError(DeviceError):
    """Bytes on the wire that do not parse: bad framing, CRC mismatch, torn reply."""


class DeviceTimeout(DeviceError, TimeoutError):
    """No complete reply within the timeout; the message names the command."""


class ConnectionLost(DeviceError, ConnectionError):
    """The connection to the device dropped."""


class RobotFault(DeviceError):
    """The robot refused or aborted a motion: protective or emergency stop, motor off,
    unreachable pose, motion not finished."""
