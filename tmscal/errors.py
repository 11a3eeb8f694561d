"""The tmscal exception tree (one root; device codes ride along).

::

    TmscalError
    ├── ConfigError        invalid or unreadable config (names file and key)
    ├── SessionError       malformed or unreadable session file (names file and line)
    ├── CalibrationError   a solve that cannot be done (too few poses, degenerate data)
    ├── SafetyError        a pose or speed outside the configured envelope; nothing was sent
    └── DeviceError        a device said no (carries ``code`` and ``text``)
        ├── ProtocolError  malformed, torn or corrupt bytes on the wire
        ├── DeviceTimeout  no (complete) reply in time; also a ``TimeoutError``
        ├── ConnectionLost the link dropped
        └── RobotFault     protective / emergency stop, motor off, unreachable pose

``ValueError`` is used only for bad arguments to pure functions (shapes, NaN).
"""

from __future__ import annotations


class TmscalError(Exception):
    """Root of every error tmscal raises on purpose."""


class ConfigError(TmscalError):
    """A config file is unreadable or invalid; the message names the file and the key."""


class SessionError(TmscalError):
    """A session file is unreadable or malformed; the message names the file and the line."""


class CalibrationError(TmscalError):
    """The data cannot give a calibration (too few poses, no rotation diversity, …)."""


class SafetyError(TmscalError):
    """A commanded pose or speed is outside the configured safety envelope; nothing was sent."""


class DeviceError(TmscalError):
    """A device reported an error. ``code`` is the device's own code (NDI ``ERRORxx`` code,
    b-CAP HRESULT, UR safety status …) and ``text`` its meaning, where known."""

    def __init__(self, message: str, code: int | str | None = None, text: str | None = None,
                 device: str | None = None) -> None:
        super().__init__(message)
        self.code = code
        self.text = text
        self.device = device


class ProtocolError(DeviceError):
    """Bytes on the wire that do not parse: bad framing, CRC mismatch, torn reply."""


class DeviceTimeout(DeviceError, TimeoutError):
    """No complete reply within the timeout; the message names the command."""


class ConnectionLost(DeviceError, ConnectionError):
    """The connection to the device dropped."""


class RobotFault(DeviceError):
    """The robot refused or aborted a motion: protective or emergency stop, motor off,
    unreachable pose, motion not finished."""
