"""The tracker section's ports and files: which ``tracker.port`` values are allowed (a device
path or ``socket://host:port``; no other pyserial URL scheme, since some open or write files
named in the URL), where the tools' ROM files and the ``tracker.log_wire`` trace are, and that
the trace never overwrites an input. Used by ``tmscal.config`` at load, by
``acquisition.devices.make_tracker`` and by the NDI driver before a port opens.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from .config_checks import err, show

__all__ = ["tracker_port_problem", "rom_path", "check_rom_exists", "log_wire_path"]


def tracker_port_problem(port: str) -> str | None:
    """Why ``port`` is not an acceptable tracker port, or None when it is: a device path
    (``/dev/ttyUSB0``, ``/dev/pts/3``, ``COM3``; no URL scheme) or ``socket://host:port``.
    Every other pyserial URL scheme (spy://, loop://, rfc2217://, hwgrep://, alt:// …) is
    refused: some of them open or write files named in the URL."""
    if not isinstance(port, str) or not port.strip():
        return "expected a device path or socket://host:port"
    if "\0" in port or any(c in port for c in "\r\n"):
        return "contains a control character"
    if "://" not in port:
        return None
    scheme, _, rest = port.partition("://")
    if scheme.lower() != "socket":
        return (f"URL scheme {scheme!r} is not allowed; use a device path (e.g. /dev/ttyUSB0) "
                "or socket://host:port")
    m = re.fullmatch(r"(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):([0-9]{1,5})", rest)
    if m is None or not 1 <= int(m.group(2)) <= 65535:
        return "expected socket://host:port (port 1…65535, no path, query or options)"
    return None


def rom_path(rom: Any, src: str, name: str, base_dir: Path | None,
              must_exist: bool = True) -> str | None:
    """The absolute path of tool ``name``'s ROM file (None: a tool already loaded)."""
    if rom is None:
        return None
    if not isinstance(rom, str) or not rom or "\0" in rom:
        raise err(src, f"tracker.tools.{name}", f"expected a ROM file path, got {show(rom)}")
    p = Path(rom)
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    if must_exist:
        check_rom_exists(src, name, str(p))
    return str(p)


def check_rom_exists(src: str, name: str, path: str | None) -> None:
    """ConfigError naming ``tracker.tools.<name>`` when its ROM file is not there (None: a
    tool already loaded in the tracker, nothing to check)."""
    if path is not None and not Path(path).is_file():
        raise err(src, f"tracker.tools.{name}", f"ROM file not found: {path}")


def log_wire_path(tracker: Any, src: str, base_dir: Path | None) -> str:
    """The absolute path of ``tracker.log_wire``: a new file in an existing directory, not an
    input (the config, a ROM file), on a serial device port. Whether it exists is checked
    again when the port opens (it must not: nothing is overwritten)."""
    raw = tracker.log_wire
    if not isinstance(raw, str) or not raw.strip() or any(c in raw for c in "\0\r\n"):
        raise err(src, "tracker.log_wire", f"expected a file path, got {show(raw)}")
    p = Path(raw).expanduser()
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    p = p.absolute()
    inputs = {Path(r).resolve() for r in tracker.tools.values() if r}
    if Path(src).is_file():
        inputs.add(Path(src).resolve())
    if p.resolve() in inputs:
        raise err(src, "tracker.log_wire", f"{p} is an input file; name a new file")
    if p.is_dir():
        raise err(src, "tracker.log_wire", f"{p} is a directory; name a new file")
    if not p.parent.is_dir():
        raise err(src, "tracker.log_wire", f"directory {p.parent} does not exist")
    if tracker.port and "://" in tracker.port:
        raise err(src, "tracker.log_wire", "the wire log records a serial device port "
                  f"(pyserial's spy://); {tracker.port!r} is not one")
    return str(p)
