"""The Polaris mock as a device: :class:`PolarisFirmware` served over a Linux pty and/or
loopback TCP (:class:`~tmscal.mocks.server.TCPListener`)."""

from __future__ import annotations

import errno
import logging
import os
import select
import socket
import threading
import tty
from collections.abc import Callable
from typing import ClassVar

from ..server import MockDevice, TCPListener
from .firmware import PolarisFirmware

log = logging.getLogger(__name__)

__all__ = ["PolarisMock"]

_POLL_S = 0.05
_READ_BYTES = 4096


class _PtyServer:
    """A new pty whose master end a daemon thread serves with ``feed(buf, data) ->
    replies``, writing ``pending()`` (what the device sends by itself) between reads;
    ``path`` is the slave (``/dev/pts/N``) clients open as a serial port."""

    def __init__(self, feed: Callable[[bytearray, bytes], list[bytes]],
                 pending: Callable[[], list[bytes]], what: str) -> None:
        self._feed = feed
        self._pending = pending
        self._stop = threading.Event()
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self.path = os.ttyname(slave)
        self._master = master
        self._fds = [master, slave]  # the slave stays open: the master reads EIO otherwise
        self._thread = threading.Thread(target=self._serve, daemon=True,
                                        name=f"{what}-pty{self.path}")
        self._thread.start()

    def _serve(self) -> None:
        master = self._master
        buf = bytearray()
        while not self._stop.is_set():
            try:
                r, _, _ = select.select([master], [], [], _POLL_S)
            except (OSError, ValueError):
                return
            for reply in self._pending():
                self._write(reply)
            if not r:
                continue
            try:
                data = os.read(master, _READ_BYTES)
            except BlockingIOError:
                continue
            except OSError as e:  # EIO while no client has the slave open (should not happen)
                if e.errno == errno.EIO:
                    self._stop.wait(0.01)
                    continue
                return
            for reply in self._feed(buf, data) if data else ():
                self._write(reply)

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        for _ in range(1000):  # bounded: give up on a reader that never drains
            if not view:
                return
            try:
                n = os.write(self._master, view)
                view = view[n:]
            except BlockingIOError:
                select.select([], [self._master], [], 0.01)
            except OSError:
                return
        log.warning("Polaris mock: pty reader not draining; reply dropped")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        for fd in self._fds:
            try:
                os.close(fd)
            except OSError:
                pass
        self._fds.clear()


class PolarisMock(PolarisFirmware, MockDevice):
    """An NDI Polaris serving ``rig`` over a pty and/or loopback TCP; the parameters are
    :class:`PolarisFirmware`'s.

    ``start()`` (and ``with``) serves on a pty unless a transport already serves, and returns
    the endpoint; :meth:`start_pty` and :meth:`start_tcp` start one transport each (a second
    call returns the running one). ``endpoints``: {"pty": path, "tcp": url} of those
    serving. ``close()`` stops both, safe twice.
    """

    TRANSPORTS: ClassVar[tuple[str, ...]] = ("pty", "tcp")

    _pty: _PtyServer | None = None
    _tcp: TCPListener | None = None
    _tcp_url: str | None = None

    @property
    def endpoints(self) -> dict[str, str]:
        """{"pty": the slave path, "tcp": ``socket://HOST:PORT``} of the transports
        serving."""
        out = {}
        if self._pty is not None:
            out["pty"] = self._pty.path
        if self._tcp_url is not None:
            out["tcp"] = self._tcp_url
        return out

    @property
    def _listeners(self) -> list[TCPListener]:
        """The TCP listeners serving (for tests checking what the mocks bind to)."""
        return [self._tcp] if self._tcp is not None else []

    def _start(self) -> str:
        if self._pty is None and self._tcp is None:
            return self.start_pty()
        return self._pty.path if self._pty is not None else str(self._tcp_url)

    def start_pty(self) -> str:
        """Serve on a new pty; returns the slave path (``/dev/pts/N``) clients open."""
        if self._pty is None:
            self._pty = _PtyServer(self._feed, self.pending_output, "polaris-mock")
            log.info("Polaris mock (%s) on %s", self.model, self._pty.path)
        return self._pty.path

    def start_tcp(self, host: str = "127.0.0.1", port: int = 0) -> str:
        """Serve on TCP ``host:port`` (loopback only: 127.0.0.0/8, ::1 or localhost, else
        ``ConfigError``; port 0 picks a free one); returns ``socket://HOST:PORT`` for
        ``serial.serial_for_url``."""
        if self._tcp is None:
            listener = TCPListener(host, port, lambda conn: self._serve_conn(conn, listener),
                                   "Polaris mock TCP host")
            self._tcp_url = f"socket://{listener.start()}"
            self._tcp = listener
            log.info("Polaris mock (%s) on %s", self.model, self._tcp_url)
        return str(self._tcp_url)

    def _close(self) -> None:
        self._stopping.set()
        if self._tcp is not None:
            self._tcp.close()
        if self._pty is not None:
            self._pty.close()
        self._tcp = self._pty = None
        self._tcp_url = None

    def _serve_conn(self, conn: socket.socket, listener: TCPListener) -> None:
        conn.settimeout(_POLL_S)
        buf = bytearray()
        while not listener.stopping:
            for reply in self.pending_output():
                conn.sendall(reply)
            try:
                data = conn.recv(_READ_BYTES)
            except TimeoutError:
                continue
            if not data:
                return
            for reply in self._feed(buf, data):
                conn.sendall(reply)
