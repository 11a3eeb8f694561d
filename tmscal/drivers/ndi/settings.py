"""The NDI tracker's config keys (``tracker: {driver: ndi, ...}``): which ``tracker.port``
values are allowed (a device path or ``socket://host:port``; no other pyserial URL scheme,
since some open or write files named in the URL), the serial rate and reply format, the tools'
ROM files and the ``tracker.log_wire`` trace (which never overwrites an input), and the
driver's options. Read by the config parser through the driver registry; ``tracker_port_problem``
is also the driver's own check before a port opens (``wire.py``).
"""

from __future__ import annotations

import dataclasses
import errno
import os
import re
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Self

from ...config.settings import Option, TrackerSettings
from ...config.values import err, show
from ...errors import ConfigError
from .codes import BAUD_CODES
from .rom import read_rom

__all__ = ["NDISettings", "tracker_port_problem", "rom_path", "check_rom_exists",
           "log_wire_path", "short_path"]


def _wait(default: float, help: str) -> Option:
    """A per-command wait the driver takes as an option (s)."""
    return Option(float, above=0, hi=120, default=default, unit="s", help=help)


#: the API port of a networked NDI tracker (the Vega), for the hint of ``tracker_port_problem``
VEGA_API_PORT = 8765

#: a network address written without ``socket://``: an IPv4 address (with or without a port),
#: a bracketed IPv6 address, or ``host:port`` (no slash, backslash or space: never a device
#: path, a pty or a Windows COM port)
_BARE_ADDRESS = re.compile(r"(?P<host>\d{1,3}(?:\.\d{1,3}){3}|\[[0-9A-Fa-f:.]+\])"
                           r"(?::(?P<port>\d{1,5}))?"
                           r"|(?P<name>[A-Za-z0-9._-]+):(?P<nport>\d{1,5})")


def tracker_port_problem(port: str) -> str | None:
    """Why ``port`` is not an acceptable tracker port, or None when it is: a device path
    (``/dev/ttyUSB0``, ``/dev/pts/3``, ``COM3``; no URL scheme) or ``socket://host:port``.
    A network address without the scheme (``192.168.1.10:8765``, ``192.168.1.10``,
    ``vega.local:8765``, ``[fe80::1]:8765``) is refused with the ``socket://`` spelling to
    use: pyserial would take it for a device path and fail only when it opens ("No such
    file or directory"). Every other pyserial URL scheme (spy://, loop://, rfc2217://,
    hwgrep://, alt:// …) is refused: some of them open or write files named in the URL."""
    if not isinstance(port, str) or not port.strip():
        return "expected a device path or socket://host:port"
    if "\0" in port or any(c in port for c in "\r\n"):
        return "contains a control character"
    if "://" not in port:
        m = _BARE_ADDRESS.fullmatch(port.strip())
        if m is None:
            return None
        host = m.group("host") or m.group("name")
        num = m.group("port") or m.group("nport") or str(VEGA_API_PORT)
        return (f"a network address without socket://; a networked tracker is written "
                f"socket://{host}:{num} (an NDI Vega's API port is {VEGA_API_PORT}); a "
                "serial tracker is a device path such as /dev/ttyUSB0 or COM3")
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


def short_path(path: Any, limit: int = 120) -> str:
    """``path`` for a message: whole when short, else its start and end around "…" (a path
    of thousands of characters would bury the message)."""
    text = str(path)
    if len(text) <= limit:
        return text
    keep = (limit - 1) // 2
    return f"{text[:keep]}…{text[-keep:]}"


def _fs_problem(e: OSError) -> str:
    """What the file system said, with the errno's name (ENAMETOOLONG, EACCES, ELOOP …)."""
    code = errno.errorcode.get(e.errno or 0)
    what = e.strerror or type(e).__name__
    return f"{what} ({code})" if code else what


def check_rom_exists(src: str, name: str, path: str | None) -> None:
    """ConfigError naming ``tracker.tools.<name>`` when its ROM file is not there or not a
    regular file, or the file system refuses the path (a name over 255 characters, no
    permission, a symbolic link loop; None: a tool already loaded in the tracker, nothing
    to check)."""
    if path is None:
        return
    key = f"tracker.tools.{name}"
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise err(src, key, f"ROM file not found: {short_path(path)}") from None
    except OSError as e:
        raise err(src, key, f"ROM file {short_path(path)}: {_fs_problem(e)}") from None
    except ValueError as e:  # an embedded NUL byte
        raise err(src, key, f"ROM file {short_path(path)}: {e}") from None
    if not stat.S_ISREG(st.st_mode):
        raise err(src, key, f"ROM file {short_path(path)}: not a regular file")


def log_wire_path(raw: Any, port: str, tools: Mapping[str, str | None], src: str,
                  base_dir: Path | None) -> str:
    """The absolute path of ``tracker.log_wire`` (``raw``): a new file in an existing
    directory, not an input (the config, a ROM file of ``tools``), on a serial device
    ``port``. Whether it exists is checked again when the port opens (it must not: nothing is
    overwritten)."""
    if not isinstance(raw, str) or not raw.strip() or any(c in raw for c in "\0\r\n"):
        raise err(src, "tracker.log_wire", f"expected a file path, got {show(raw)}")
    p = Path(raw).expanduser()
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    p = p.absolute()
    try:
        inputs = {_resolved(r) for r in [*tools.values(), src] if r} - {None}
        if p.resolve() in inputs:
            raise err(src, "tracker.log_wire", f"{short_path(p)} is an input file; name a new "
                      "file")
        if p.is_dir():
            raise err(src, "tracker.log_wire", f"{short_path(p)} is a directory; name a new "
                      "file")
        if not p.parent.is_dir():
            raise err(src, "tracker.log_wire", f"directory {short_path(p.parent)} does not "
                      "exist")
    except OSError as e:  # a name too long, no permission: the path, not a raw OSError
        raise err(src, "tracker.log_wire", f"{short_path(p)}: {_fs_problem(e)}") from None
    except RuntimeError as e:  # Path.resolve on a symbolic link loop
        raise err(src, "tracker.log_wire", f"{short_path(p)}: {e}") from None
    _check_wire_port(port, src)
    return str(p)


def _resolved(path: str) -> Path | None:
    """``path`` resolved, or None when the file system cannot resolve it (a loop, a name
    too long): such a path names no file that the wire log could overwrite."""
    try:
        return Path(path).resolve()
    except (OSError, RuntimeError):
        return None


def _check_wire_port(port: str, src: str) -> None:
    if port and "://" in port:
        raise err(src, "tracker.log_wire", "the wire log records a serial device port "
                  f"(pyserial's spy://); {port!r} is not one")


@dataclass(frozen=True)
class NDISettings(TrackerSettings):
    """An NDI tracker (Polaris Vicra/Spectra over serial, Vega over TCP): ``port`` (a
    device path, a pty, or ``socket://host:port``; "": give it on the command line),
    ``baud`` (bit/s after the reset, a Combined API COMM rate), ``reply`` ("bx" binary or
    "tx" text tracking replies), ``log_wire`` (a new file recording the serial traffic,
    absolute once parsed, or None) and the tools' ROM files (absolute, or None for a tool
    already loaded). Options: per-reply timeout, retries, reset, the slow commands' waits
    (s) and the tracking reply option bits (docs/devices.md)."""

    KEYS: ClassVar[tuple[str, ...]] = ("port", "baud", "reply", "log_wire")
    ADDRESS_KEY: ClassVar[str] = "port"
    #: from the Polaris Vicra's 20 Hz (Spectra 20, 30 or 60 Hz; Aurora 40 Hz) to the fastest
    #: Polaris Vega; a rate outside is a typo or another device's
    FRAME_RATE_HZ: ClassVar[tuple[float, float] | None] = (20.0, 400.0)
    FRAME_RATE_DEVICES: ClassVar[str] = "NDI Polaris Vicra 20 Hz, Spectra 20–60 Hz, Vega"
    OPTIONS: ClassVar[Mapping[str, Option]] = {
        "timeout_s": _wait(2.0, "the wait for each reply"),
        "retries": Option(int, lo=0, hi=100, default=3,
                          help="re-sends of a command after a corrupt, torn or missing reply"),
        "reset": Option(bool, null=True, default=None,
                        default_text="null: only when every tool has a ROM file",
                        help="send a serial break first (never over `socket://`)"),
        "reset_timeout_s": _wait(7.0, "the wait for RESET after the break"),
        "init_timeout_s": _wait(5.0, "the wait for INIT"),
        "pinit_timeout_s": _wait(5.0, "the wait for each PINIT"),
        "tstart_timeout_s": _wait(5.0, "the wait for TSTART"),
        "reply_options": Option(int, lo=0, hi=0xFFFF, default=0x0801,
                                default_text="2049 (0x0801: transforms, out-of-volume "
                                             "included)",
                                help="the TX/BX reply option word"),
    }
    MOVED: ClassVar[Mapping[str, str]] = {"options.options": "options.reply_options"}

    port: str = ""
    baud: int = 115200
    reply: str = "bx"
    log_wire: str | None = None

    @classmethod
    def parse(cls, section: Mapping[str, Any], src: str, base_dir: Path | None,
              check_files: bool) -> Self:
        """The NDI keys of ``section``: reply bx or tx, an acceptable port, a COMM baud
        rate, ROM files (relative paths against ``base_dir``; that they exist is checked
        unless ``check_files`` is False) and the wire log's path."""
        s = super().parse(section, src, base_dir, check_files)
        if s.reply not in ("bx", "tx"):
            raise err(src, "tracker.reply", f"expected 'bx' or 'tx', got {s.reply!r}")
        if s.port:
            problem = tracker_port_problem(s.port)
            if problem:
                raise err(src, "tracker.port", f"{show(s.port)}: {problem}")
        if s.baud not in BAUD_CODES:
            raise err(src, "tracker.baud", f"expected a COMM rate of the NDI Combined API "
                      f"({', '.join(map(str, sorted(BAUD_CODES)))}), got {s.baud}")
        if s.log_wire is not None:
            s = dataclasses.replace(
                s, log_wire=log_wire_path(s.log_wire, s.port, s.tools, src, base_dir))
        return s

    @classmethod
    def parse_tool(cls, name: str, value: Any, src: str, base_dir: Path | None,
                   check_files: bool) -> str | None:
        """Tool ``name``'s ROM file, absolute (None: a tool already loaded)."""
        return rom_path(value, src, name, base_dir, check_files)

    def kwargs(self) -> dict[str, Any]:
        """``port``, ``tools`` (ROM files), ``baud``, ``reply``, ``log_wire`` for
        ``NDITracker``. ConfigError when no port is given or a ROM file is not there (a
        config loaded with ``check_files=False``)."""
        if not self.port:
            raise self.err("port", "no port given (a device such as /dev/ttyUSB0, a pty path, "
                           "or socket://host:port)")
        for name, rom in self.tools.items():
            check_rom_exists(self.src, name, rom)
        return super().kwargs()

    def preflight(self) -> list[str]:
        """The dry run's offline checks: every ROM file is read and checked as the driver
        checks it before uploading (:func:`.rom.read_rom`: at most 1024 bytes, starting with
        ``NDI``, binary; a YAML or text file is refused), ``ConfigError`` naming
        ``tracker.tools.<name>`` and the file; and what the port is (its form was checked
        when the config was read; whether anything answers there is not checked offline)."""
        lines = []
        for name, rom in self.tools.items():
            if rom is None:
                lines.append(f"tool {name}: no ROM file (a tool the tracker has loaded)")
                continue
            check_rom_exists(self.src, name, rom)
            try:
                data = read_rom(name, rom)
            except ConfigError as e:
                raise err(self.src, f"tracker.tools.{name}",
                          str(e).removeprefix(f"tool {name!r}: ")) from None
            lines.append(f"tool {name}: {short_path(rom)}: an NDI tool definition "
                         f"({len(data)} bytes)")
        if not self.port:
            lines.append("port: none in the config (give --tracker-port)")
        elif self.port.lower().startswith("socket://"):
            lines.append(f"port {self.port}: a networked tracker (that it answers there is "
                         "checked when it connects: tmscal track)")
        else:
            lines.append(f"port {self.port}: a serial device (that the tracker answers there "
                         "is checked when it connects: tmscal track)")
        return lines

    def address(self) -> str:
        """The serial device or ``socket://host:port`` URL ("" when the config gives none)."""
        return self.port

    def with_address(self, text: str) -> Self:
        """These settings on port ``text`` (checked as ``tracker.port`` is)."""
        problem = tracker_port_problem(text)
        if problem:
            raise self.err("port", f"{show(text)} (the address given instead of the config's, "
                           f"e.g. by --tracker-port): {problem}")
        if self.log_wire is not None:
            _check_wire_port(text, self.src)
        return dataclasses.replace(self, port=text)
