"""Tool-definition (.rom) files of NDI passive tools: read and checked here, the one place,
before anything is sent to the tracker (which may be a networked one, ``socket://host``).

What a tool definition is, as far as the upload relies on it:

* It is an SROM image written to the tracker with PVWR in 64-byte chunks at addresses
  0000…03C0 (NDI Polaris API Guide, PVWR; ndicapi's ``ndiPVWRFromFile`` reads at most 1024
  bytes of the file and writes those 16 chunks; docs/devices.md). So an image holds at most
  :data:`ROM_MAX_BYTES` = 1024 bytes: a bigger file cannot be a tool definition, and reading
  one whole (``/dev/zero``, a video, a disk image) is refused before it is read.
* It begins with the ASCII bytes ``NDI`` (:data:`ROM_MAGIC`): the layout that jhu-saw's
  sawNDITracker tool converter reads and writes (reverse-engineered from NDI's 752-byte
  files: ``NDI``, a checksum, tool type, marker geometry as float32 …) starts so, and so do
  the synthetic files the mocks use (``configs/tools/README.md``).
* It is binary: float32 marker positions and zero padding. A file without a NUL byte that
  decodes as UTF-8 is text (a YAML or config file named by mistake) and is refused.

Nothing else is checked: the checksum and the fields after the magic are not verified (their
meaning comes from a reverse-engineered description, not from NDI), so a file that passes
may still be refused by the tracker (PINIT: ERROR40 invalid tool definition).
"""

from __future__ import annotations

import ipaddress
import logging
import os
import stat
from collections.abc import Mapping
from pathlib import Path

from ...errors import ConfigError

log = logging.getLogger(__name__)

__all__ = ["ROM_MAX_BYTES", "ROM_MAGIC", "rom_problem", "read_rom", "read_roms",
           "remote_host"]

#: the largest tool definition PVWR can write: 16 chunks of 64 bytes (0000…03C0)
ROM_MAX_BYTES = 1024
#: the first bytes of an NDI tool definition
ROM_MAGIC = b"NDI"


def rom_problem(data: bytes) -> str | None:
    """Why ``data`` (a whole file) is not an NDI tool definition, or None: empty, over
    :data:`ROM_MAX_BYTES`, not starting with ``NDI``, or text (no NUL byte, valid UTF-8)."""
    if not data:
        return "the file is empty"
    if len(data) > ROM_MAX_BYTES:
        return _too_big(len(data))
    if not data.startswith(ROM_MAGIC):
        return (f"does not start with {ROM_MAGIC.decode()!r} as an NDI tool definition does "
                f"(first bytes {data[:8]!r})")
    if b"\0" not in data and _is_utf8(data):
        return ("a text file, not a binary tool definition (no zero byte, all UTF-8): "
                "a config or YAML file named as a ROM?")
    return None


def _too_big(size: int) -> str:
    return (f"{size} bytes; an NDI tool definition (SROM image) is at most {ROM_MAX_BYTES} "
            "bytes (PVWR writes 16 chunks of 64)")


def _is_utf8(data: bytes) -> bool:
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


def read_rom(tool: str, path: str | os.PathLike[str]) -> bytes:
    """The tool definition of ``tool`` from ``path``, checked (:func:`rom_problem`).
    ``ConfigError`` naming the tool and the file when it cannot be read, is not a regular
    file, or is not a tool definition; at most ``ROM_MAX_BYTES + 1`` bytes are ever read."""
    p = Path(path)
    where = f"tool {tool!r}: ROM file {p}"
    try:
        # O_NONBLOCK: opening a FIFO named as a ROM must not wait for a writer
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise ConfigError(f"{where}: cannot read it: {e.strerror or e}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ConfigError(f"{where}: not a regular file")
        if st.st_size > ROM_MAX_BYTES:  # said with its size, without reading it
            raise ConfigError(f"{where}: not an NDI tool definition: {_too_big(st.st_size)}")
        data = b""
        while len(data) <= ROM_MAX_BYTES:
            chunk = os.read(fd, ROM_MAX_BYTES + 1 - len(data))
            if not chunk:
                break
            data += chunk
    except OSError as e:
        raise ConfigError(f"{where}: cannot read it: {e.strerror or e}") from None
    finally:
        os.close(fd)
    problem = rom_problem(data)
    if problem:
        raise ConfigError(f"{where}: not an NDI tool definition: {problem}")
    return data


def remote_host(port: str) -> str | None:
    """The host of a ``socket://host:port`` tracker port when it is not this computer, else
    None (a device path; a loopback address: 127.0.0.0/8, ::1, ``localhost``). A host name
    other than ``localhost`` counts as remote (it is not resolved here)."""
    scheme, sep, rest = port.partition("://")
    if not sep or scheme.lower() != "socket":
        return None
    host = rest.rpartition(":")[0].strip("[]")
    if host.lower().rstrip(".") == "localhost" or host.lower().endswith(".localhost"):
        return None
    try:
        if ipaddress.ip_address(host).is_loopback:
            return None
    except ValueError:
        pass  # a host name
    return host


def read_roms(paths: Mapping[str, str | os.PathLike[str] | None],
              port: str | None = None) -> dict[str, bytes]:
    """Tool name → checked tool definition, for every tool that has a ROM file (None: a tool
    already loaded on the device). The first bad file raises (:func:`read_rom`). ``port``:
    the tracker port they are for; when it is ``socket://`` to a host other than this
    computer (:func:`remote_host`), a warning names the host and the tools."""
    roms = {tool: read_rom(tool, path) for tool, path in paths.items() if path is not None}
    host = remote_host(port) if port is not None else None
    if roms and host is not None:
        log.warning("ndi: uploading ROM files to a remote host: %s (%s) receives the tool "
                    "definitions of %s; make sure it is the tracker you mean", host, port,
                    ", ".join(sorted(roms)))
    return roms
