"""Opening the NDI tracker's port: the port check, pyserial's ``serial_for_url`` at 9600 baud
8N1 (the device's rate after a reset), and the optional wire log.

The wire log (``tracker.log_wire``) records every byte both ways as pyserial's ``spy://``
hex dump, so a lab can send a trace when something fails. It is the one way tmscal uses
``spy://``: the port check refuses a ``spy://`` port in the config, and the URL is built
here from the configured device path and the log file. The file must not exist (nothing is
overwritten, an input file least of all); ``spy://`` wraps a local serial device only, so a
``socket://`` port with a wire log is refused.
"""

from __future__ import annotations

import urllib.parse
from pathlib import Path
from typing import Any

import serial

from ...errors import ConfigError, ConnectionLost
from ...net import connect_problem
from .rom import remote_host
from .settings import VEGA_API_PORT, tracker_port_problem

__all__ = ["open_port", "wire_log_problem", "spy_url", "remote_host", "silence_message"]

_READ_SLICE_S = 0.05
#: how long pyserial's socket:// handler waits for the TCP connection (its POLL_TIMEOUT, s)
_SOCKET_CONNECT_S = 5.0


def wire_log_problem(port: str, log_file: Path) -> str | None:
    """Why ``log_file`` cannot record the traffic of ``port``, or None."""
    if "://" in port:
        return ("the wire log records a serial device (spy:// wraps a local port); "
                f"{port!r} is not one")
    if any(c in port for c in "?#&"):
        return f"port {port!r} cannot be combined with a wire log (contains ? # or &)"
    if log_file.exists() or log_file.is_symlink():
        return f"{log_file} exists; name a new file (the wire log overwrites nothing)"
    if not log_file.parent.is_dir():
        return f"directory {log_file.parent} does not exist"
    return None


def spy_url(port: str, log_file: Path) -> str:
    """pyserial's ``spy://PORT?file=LOG`` (the file name quoted for its query parser)."""
    return f"spy://{port}?file={urllib.parse.quote(str(log_file), safe='/')}"


def open_port(device: str, port: str, write_timeout_s: float, log_file: Path | None) -> Any:
    """The opened port at 9600 baud 8N1: ``port`` (a device path or ``socket://host:port``,
    checked again here) or, with ``log_file``, the same device through ``spy://``.
    ``ConfigError`` for a refused port or log file (naming ``tracker.port`` /
    ``tracker.log_wire``), ``ConnectionLost`` when the port cannot be opened."""
    # defence in depth (the config refuses these first): pyserial's other URL handlers
    # (spy://…?file=, loop://, rfc2217:// …) can open or write files named in the URL
    problem = tracker_port_problem(port)
    if problem:
        raise ConfigError(f"{device}: key 'tracker.port': {port!r} refused: {problem}")
    url = port
    if log_file is not None:
        problem = wire_log_problem(port, log_file)
        if problem:
            raise ConfigError(f"{device}: key 'tracker.log_wire': {problem}")
        url = spy_url(port, log_file)
    try:
        return serial.serial_for_url(url, baudrate=9600, bytesize=8, parity="N", stopbits=1,
                                     timeout=_READ_SLICE_S, write_timeout=write_timeout_s)
    except (serial.SerialException, OSError, ValueError) as e:
        scheme, _, rest = port.partition("://")
        why = None
        if scheme.lower() == "socket":
            host, _, num = rest.rpartition(":")
            why = connect_problem(e, host.strip("[]"), num, "tracker.port",
                                  _SOCKET_CONNECT_S, service="the tracker's API; on a Vega "
                                  f"port {VEGA_API_PORT}")
        raise ConnectionLost(f"{device}: cannot open {port}: {why or e}", device=device) from e


def silence_message(device: str, port: str, baud: int, broke: bool) -> str:
    """What to check when nothing at all answered on ``port`` since it was opened: not the
    serial break (``broke``: one was sent), nor INIT at 9600 baud and at ``baud``; for a
    ``socket://`` port, INIT. One line naming the port and what to check."""
    if port.lower().startswith("socket://"):
        return (f"{device}: nothing answered on {port} (no reply to INIT): check the address "
                "and port (tracker.port) and that the tracker is powered on and on this network")
    rates = "9600" if baud == 9600 else f"9600 and {baud}"
    return (f"{device}: nothing answered on {port} (no reply to "
            + ("the serial break, nor to " if broke else "") + f"INIT at {rates} baud): check "
            "that the tracker is powered on (its self-test finished), that its cable is plugged "
            "in at both ends and that this is its port (tracker.port), and the baud rate "
            f"(tracker.baud: {baud})")
