"""One tmscal process per robot: an OS-level lock on the robot's address, taken when a
:class:`~tmscal.drivers.base.Robot` opens and released when it closes.

Without it a second ``tmscal acquire`` (on another session file) or ``tmscal robot`` could
connect to a robot that a run is driving, and take it over: on a UR, uploading its own control
script stops the first run's. The lock is ``flock`` on a file named after the driver and the
address (``ur-127.0.0.2-….lock``) in a per-user directory: ``$TMSCAL_LOCK_DIR`` if set, else
``$XDG_RUNTIME_DIR/tmscal-locks``, else ``<temp dir>/tmscal-locks-<uid>`` (created 0700 and
refused when another user owns it). The kernel drops the lock when the process ends, however it
ends (kill -9 included): no stale lock outlives its holder. The file holds the holder's pid,
which the refusal names.

Addresses are compared as text, host lower-cased and IP literals in their canonical form: two
names for one robot (``localhost`` and ``127.0.0.1``, a host name and its address) are not
recognised as the same.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import ipaddress
import os
import re
import stat
import tempfile
from pathlib import Path

from ..errors import SafetyError

__all__ = ["LOCK_DIR_ENV", "RobotLock", "host_port", "lock_dir", "normalise_address"]

#: environment variable naming the lock directory (tests give each session its own)
LOCK_DIR_ENV = "TMSCAL_LOCK_DIR"


def lock_dir() -> Path:
    """The per-user directory of robot lock files (see the module doc), created 0700.
    ``SafetyError`` when it cannot be created or is not a directory this user owns."""
    env = os.environ.get(LOCK_DIR_ENV)
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if env:
        d = Path(env)
    elif runtime and Path(runtime).is_dir():
        d = Path(runtime) / "tmscal-locks"
    else:
        d = Path(tempfile.gettempdir()) / f"tmscal-locks-{os.getuid()}"
    try:
        d.mkdir(mode=0o700, parents=bool(env), exist_ok=True)
        st = d.lstat()
    except OSError as e:
        raise SafetyError(f"cannot create the robot lock directory {d}: {e.strerror or e} "
                          f"(set {LOCK_DIR_ENV} to a directory of yours)") from None
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid():
        raise SafetyError(f"robot lock directory {d} is not a directory of this user; "
                          f"remove it or set {LOCK_DIR_ENV} to a directory of yours")
    return d


def normalise_address(address: str) -> str:
    """``address`` as the lock compares it: stripped, lower-cased, an IP literal (alone, as
    ``host:port`` or as ``[v6]:port``) in its canonical form."""
    a = address.strip().lower()
    m = re.fullmatch(r"\[([^\]]+)\]:(\d+)|([^:]+):(\d+)", a)
    host, port = (m.group(1) or m.group(3), m.group(2) or m.group(4)) if m else (a, None)
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return a
    if port is None:
        return ip.compressed
    return f"[{ip.compressed}]:{port}" if ip.version == 6 else f"{ip.compressed}:{port}"


def host_port(host: str, port: int) -> str:
    """``host:port`` (``[host]:port`` for an IPv6 literal), for ``Robot.lock_address``."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class RobotLock:
    """The lock of robot ``address`` driven by ``driver`` ("ur", "denso" …). ``acquire()``
    takes it or raises ``SafetyError`` naming the address and the pid that holds it;
    ``release()`` gives it back (safe twice)."""

    def __init__(self, driver: str, address: str) -> None:
        self.driver = driver
        self.address = normalise_address(address)
        key = f"{driver}\0{self.address}".encode()
        safe = re.sub(r"[^a-z0-9.-]+", "_", f"{driver}-{self.address}")[:80]
        self.name = f"{safe}-{hashlib.sha256(key).hexdigest()[:12]}.lock"
        self.path: Path | None = None
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> RobotLock:
        """Take the lock (idempotent). ``SafetyError`` when another tmscal process, or
        another open robot in this one, holds it: nothing has been sent to the robot."""
        if self._fd is not None:
            return self
        path = lock_dir() / self.name
        flags = (os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
                 | getattr(os, "O_NOFOLLOW", 0))
        while True:
            try:
                fd = os.open(path, flags, 0o600)
            except OSError as e:
                raise SafetyError(f"{self.driver} {self.address}: cannot open the robot lock "
                                  f"{path}: {e.strerror or e}") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                holder = _holder(fd)
                os.close(fd)
                if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise SafetyError(f"{self.driver} {self.address}: cannot lock {path}: "
                                      f"{e.strerror or e}") from None
                raise SafetyError(
                    f"{self.driver} robot {self.address} is in use by another tmscal "
                    f"({holder}): one tmscal run per robot; wait for it to finish or stop "
                    f"it (lock {path})") from None
            if _same_file(fd, path):
                break
            os.close(fd)    # the holder released and removed it meanwhile: take a new one
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n{self.driver} {self.address}\n".encode())
        except OSError:
            pass    # the pid is for the message only; the lock is what counts
        self._fd, self.path = fd, path
        return self

    def release(self) -> None:
        """Remove the lock file and release the lock (safe twice)."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            if self.path is not None:
                self.path.unlink(missing_ok=True)   # still ours: nobody can lock it now
        except OSError:
            pass
        try:
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)


def _holder(fd: int) -> str:
    """"pid N" from a lock file's first line, or "pid unknown"."""
    try:
        first = os.pread(fd, 64, 0).split(b"\n", 1)[0].strip()
    except OSError:
        first = b""
    return f"pid {int(first)}" if first.isdigit() else "pid unknown"


def _same_file(fd: int, path: Path) -> bool:
    """Whether ``path`` still names the file open as ``fd`` (a releasing holder unlinks it)."""
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)
