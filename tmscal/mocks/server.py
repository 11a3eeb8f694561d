"""What every mock device shares: a lifecycle (``start()`` returns the endpoint string,
``close()`` stops, safe twice; ``with`` starts and closes) and a loopback TCP listener that
serves each connection in its own daemon thread and shuts every open connection on close.

A mock subclasses ``MockDevice`` and fills ``_start`` / ``_close``; its servers are
``TCPListener``s whose ``handler(conn)`` speaks the device's protocol (python-urx's fake
robot and ``socketserver`` are the models). Binding is loopback only (``tmscal.net``).
"""

from __future__ import annotations

import logging
import socket
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar

from ..net import listen_error, loopback_family, url_host

log = logging.getLogger(__name__)

__all__ = ["MockDevice", "TCPListener"]

_ACCEPT_POLL_S = 0.1


class TCPListener:
    """A TCP server on a loopback ``host:port`` (port 0: an ephemeral one). ``start()``
    binds, listens and accepts in a daemon thread; each connection is served by
    ``handler(conn)`` in its own daemon thread (TCP_NODELAY set) and closed when the
    handler returns. ``drop_all()`` shuts the open connections (a fault); ``close()`` stops
    accepting and drops them. ``what`` names the listener in errors and thread names."""

    def __init__(self, host: str, port: int, handler: Callable[[socket.socket], None],
                 what: str, backlog: int = 8) -> None:
        self.family = loopback_family(host, what)  # refuses a non-loopback host at once
        self.host = host
        self.port = int(port)
        self.handler = handler
        self.what = what
        self.backlog = backlog
        self.accepted = 0
        self._sock: socket.socket | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._conns: set[socket.socket] = set()
        self._threads: list[threading.Thread] = []

    @property
    def endpoint(self) -> str:
        """``"host:port"`` (an IPv6 host in brackets)."""
        return f"{url_host(self.host)}:{self.port}"

    def start(self) -> str:
        """Bind and serve; returns the endpoint. Safe to call twice."""
        if self._sock is not None:
            return self.endpoint
        s = socket.socket(self.family, socket.SOCK_STREAM)
        try:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((self.host, self.port))
            s.listen(self.backlog)
        except OSError as e:
            s.close()
            raise listen_error(e, self.what, self.host, self.port) from e
        s.settimeout(_ACCEPT_POLL_S)
        self._sock = s
        self.port = s.getsockname()[1]
        self._spawn(self._accept_loop, f"{self.what}:{self.port}")
        return self.endpoint

    def _spawn(self, target: Callable[..., Any], name: str, *args: Any) -> None:
        t = threading.Thread(target=target, args=args, name=name, daemon=True)
        t.start()
        with self._lock:
            self._threads = [x for x in self._threads if x.is_alive()] + [t]

    def _accept_loop(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                conn, addr = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._conns.add(conn)
                self.accepted += 1
            self._spawn(self._serve, f"{self.what}:{addr[1]}", conn)

    def _serve(self, conn: socket.socket) -> None:
        try:
            self.handler(conn)
        except OSError as e:
            log.info("%s: connection ended: %s", self.what, e)
        finally:
            with self._lock:
                self._conns.discard(conn)
            try:
                conn.close()
            except OSError:  # pragma: no cover
                pass

    def getsockname(self) -> Any:
        """The bound address of the listening socket (as ``socket.getsockname()``), so tests
        can check what a mock listens on. Raises ``OSError`` before ``start()``."""
        if self._sock is None:
            raise OSError(f"{self.what}: not listening")
        return self._sock.getsockname()

    @property
    def connections(self) -> int:
        """How many connections are open now."""
        with self._lock:
            return len(self._conns)

    def drop_all(self) -> None:
        """Shut every open connection (the handlers then see the peer gone)."""
        with self._lock:
            conns = list(self._conns)
        for c in conns:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def close(self, join_s: float = 2.0) -> None:
        """Stop accepting, drop every connection and join the threads (safe twice)."""
        self._stop.set()
        if self._sock is not None:
            try:
                self._sock.close()
            except OSError:  # pragma: no cover
                pass
        self.drop_all()
        with self._lock:
            threads = list(self._threads)
        for t in threads:
            if t is not threading.current_thread():
                t.join(timeout=join_s)

    @property
    def stopping(self) -> bool:
        """True once ``close()`` was called (handlers poll it to end their loops)."""
        return self._stop.is_set()


class MockDevice(ABC):
    """The lifecycle every mock shares: ``start()`` serves and returns the endpoint string
    the matching driver connects to; ``close()`` stops serving (safe twice, and safe after a
    failed start); ``with mock:`` starts and closes.

    ``TRANSPORTS`` says what a tracker's mock can serve on, through ``start_pty()`` (a new
    pty, as a serial line) and ``start_tcp(host, port)`` (loopback TCP): the mock rig
    (``mocks.launch``) serves a tracker on a pty only when "pty" is listed, else on TCP."""

    #: the transports the mock serves on: "tcp" (loopback), "pty" (a serial line)
    TRANSPORTS: ClassVar[tuple[str, ...]] = ("tcp",)

    _started = False

    def start(self) -> str:
        """Start serving; returns the endpoint (e.g. "127.0.0.1:5007", "/dev/pts/7")."""
        ep = self._start()
        self._started = True
        return ep

    def close(self) -> None:
        """Stop serving and close every connection (safe twice)."""
        self._close()
        self._started = False

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @abstractmethod
    def _start(self) -> str: ...

    @abstractmethod
    def _close(self) -> None: ...
