"""The OpenIGTLink tracker mock as a device: a PlusServer-like TCP server on loopback that
streams the rig's frames to every connected client."""

from __future__ import annotations

import logging
import select
import socket
import threading
import time
from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from ...drivers.igtl import wire
from ...drivers.igtl.tracker import DEFAULT_PORT
from ...errors import ConfigError, ProtocolError
from ...sim.rig import SimRig
from ..bodies import Volume
from ..clock import REAL_TIME, Clock
from ..polaris.model import MeasurementVolume
from ..server import MockDevice, TCPListener
from .frames import STATUS_OK, Frame, FrameSource
from .model import IGTLFaults, default_device_name

log = logging.getLogger(__name__)

__all__ = ["IGTLTrackerMock"]

_POLL_S = 0.05
#: how long a send to one client may block before the client is dropped (PlusServer:
#: ``DefaultClientSendTimeoutSec`` 0.5 s)
_SEND_TIMEOUT_S = 0.5
#: the most frames sent at once by a sender that woke up late (PlusServer:
#: ``MaxNumberOfIgtlMessagesToSend`` 100)
_MAX_BURST = 100
_GARBAGE = b"\xde\xad\xbe\xef not OpenIGTLink " * 4


class _Client:
    """One connection: its socket, the header version it is answered with (raised to the
    highest version it has sent, as PlusServer does), and the frames sent to it."""

    def __init__(self, conn: socket.socket, version: int) -> None:
        self.conn = conn
        self.version = version
        self.frames = 0
        self.closed = False
        self._lock = threading.Lock()

    def send(self, data: bytes) -> None:
        """Send ``data`` whole; a client that does not take it in time is dropped."""
        if self.closed or not data:
            return
        with self._lock:
            try:
                self.conn.sendall(data)
            except OSError as e:  # a timeout, a reset: PlusServer drops such a client
                log.info("OpenIGTLink mock: dropping a client (%s)", e)
                self.drop()

    def drop(self) -> None:
        """Close the connection (the handler then sees it end)."""
        self.closed = True
        try:
            self.conn.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass


class IGTLTrackerMock(MockDevice):
    """A PlusServer-like OpenIGTLink tracker serving ``rig``.

    Parameters (keyword-only after ``rig`` and ``tools``):

    * ``tools``: rig body → TRANSFORM device name (None: every body of the rig, named
      ``MarkerToTracker``, ``ProbeToTracker`` …).
    * ``host``, ``port``: where it listens (loopback only, else ``ConfigError``; port 0 picks
      a free one).
    * ``clock``: real time (frames at ``rate_hz``) or fast (frames at ``fast_rate_hz``,
      stamped as if at ``rate_hz``; see the package docstring).
    * ``volume``: :class:`~tmscal.mocks.polaris.MeasurementVolume` (default) or None.
    * ``faults``: :class:`IGTLFaults`; ``seed`` seeds their RNG.
    * ``header_version``: the header version clients get until they send a higher one
      (PlusServer's ``ClientHeaderVersion``, 1 unless configured).
    * ``send_invalid``: also send unseen tools, as the identity with their status
      (PlusServer's ``SendValidTransformsOnly="FALSE"``; its default sends valid ones only).
    """

    #: OpenIGTLink runs over TCP: the mock rig serves it on TCP whatever transport is asked
    TRANSPORTS: ClassVar[tuple[str, ...]] = ("tcp",)

    def __init__(self, rig: SimRig, tools: Mapping[str, str] | None = None, *,
                 host: str = "127.0.0.1", port: int = DEFAULT_PORT, clock: Clock = REAL_TIME,
                 volume: Volume | None = MeasurementVolume(),
                 faults: IGTLFaults | None = None, seed: int = 0, rate_hz: float = 60.0,
                 fast_rate_hz: float = 1000.0, header_version: int = 1,
                 send_invalid: bool = False) -> None:
        names = dict(tools) if tools is not None else {
            b: default_device_name(b) for b in rig.bodies}
        for body, dev in names.items():
            if body not in rig.bodies:
                raise ValueError(f"tool {body!r} is not a body of the rig ({rig.bodies})")
            if not isinstance(dev, str) or not dev.isascii() \
                    or not 0 < len(dev) <= wire.MAX_NAME_BYTES:
                raise ValueError(f"tool {body!r}: device name {dev!r} must be 1…"
                                 f"{wire.MAX_NAME_BYTES} ASCII characters")
        self.faults = faults or IGTLFaults()
        for body in (*self.faults.drop_tools, *self.faults.stale_tools):
            if body not in names:
                raise ValueError(f"IGTLFaults: {body!r} is not one of the tools {list(names)}")
        for name, v in (("rate_hz", rate_hz), ("fast_rate_hz", fast_rate_hz)):
            if isinstance(v, bool) or not isinstance(v, int | float) or not 0 < v <= 10000:
                raise ValueError(f"IGTLTrackerMock: {name} must be in (0, 10000] Hz, got {v!r}")
        if header_version not in (1, 2):
            raise ValueError(f"IGTLTrackerMock: header_version must be 1 or 2, got "
                             f"{header_version!r}")
        self.rig = rig
        self.tools = names
        self.host, self.port = host, port
        self.clock = clock
        self.rate_hz = float(rate_hz)
        self.fast_rate_hz = float(fast_rate_hz)
        self.header_version = int(header_version)
        self._frames = FrameSource(rig, names, volume, self.faults,
                                   np.random.default_rng(seed), bool(send_invalid))
        self._listener = TCPListener(host, port, self._serve_conn, "OpenIGTLink mock")
        self._clients: set[_Client] = set()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._served = 0  # frames generated (the fast clock's tracker time)
        self._t0_utc, self._t0_mono = time.time(), time.monotonic()

    # --- lifecycle ---------------------------------------------------------------------------
    def _start(self) -> str:
        return self.start_tcp(self.host, self.port)

    def start_tcp(self, host: str | None = None, port: int | None = None) -> str:
        """Listen on ``host:port`` (default: the constructor's) and stream; returns
        ``"host:port"``. A second call returns the running endpoint."""
        if self._thread is None:
            if (host, port) != (None, None) and (host, port) != (self.host, self.port):
                self._listener = TCPListener(host or self.host,
                                             self.port if port is None else port,
                                             self._serve_conn, "OpenIGTLink mock")
            endpoint = self._listener.start()
            self.host, self.port = self._listener.host, self._listener.port
            self._stop.clear()
            self._thread = threading.Thread(target=self._broadcast, daemon=True,
                                            name=f"igtl-mock:{self.port}")
            self._thread.start()
            log.info("OpenIGTLink tracker mock on %s (%s)", endpoint, self.tools)
        return self._listener.endpoint

    def start_pty(self) -> str:
        """OpenIGTLink runs over TCP only: ``ConfigError``."""
        raise ConfigError("the OpenIGTLink tracker mock serves TCP only (host:port), not a pty")

    @property
    def endpoint(self) -> str:
        """``"host:port"`` it listens on (after ``start()``)."""
        return self._listener.endpoint

    @property
    def _listeners(self) -> list[TCPListener]:
        """The TCP listener (for tests checking what the mocks bind to)."""
        return [self._listener]

    def _close(self) -> None:
        self._stop.set()
        self._listener.close()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._thread = None

    def drop_connections(self) -> None:
        """Close every client's connection now (a fault: the server went away)."""
        with self._lock:
            clients = list(self._clients)
        for c in clients:
            c.drop()

    @property
    def connections(self) -> int:
        """How many clients are connected."""
        with self._lock:
            return len(self._clients)

    def tracker_time_s(self) -> float:
        """The tracker's time (s): on the fast clock the frames generated / ``rate_hz`` (it
        advances only while a client is connected); else the clock's. The mock rig makes it
        the sim rig's time base on the fast clock."""
        return self._served / self.rate_hz if self.clock.fast else self.clock.now()

    # --- streaming ---------------------------------------------------------------------------
    def _broadcast(self) -> None:
        """Generate frames at the clock's pace while any client is connected, and send each
        to every client (PlusServer's data sender thread). On the real-time clock frame k of a
        stream is due, and stamped, at ``k / rate_hz`` s after the stream started (a tracker's
        own clock); a sender that wakes up late sends the frames it missed at once, each with
        its own stamp, at most ``_MAX_BURST`` (PlusServer sends the tracked frames since the
        last one it sent, up to ``MaxNumberOfIgtlMessagesToSend``), so the stream keeps
        ``rate_hz`` on a busy host. The fast clock's rate is a pace: a late frame is not made
        up."""
        period = 1.0 / (self.fast_rate_hz if self.clock.fast else self.rate_hz)
        due = time.monotonic()
        while not self._stop.is_set():
            wait = due - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                return
            n = 1
            if not self.clock.fast:
                behind = int((time.monotonic() - due) / period)
                if behind >= _MAX_BURST:  # the oldest are gone, as from a tracker's buffer
                    due += (behind - _MAX_BURST + 1) * period
                    behind = _MAX_BURST - 1
                n += behind
            with self._lock:  # a frame counts only for the clients connected when it is made
                clients = [c for c in self._clients if not c.closed]
                frames = ([self._next_frame(due + i * period) for i in range(n)]
                          if clients else [])
            if not frames:
                self._stop.wait(_POLL_S)
                due = time.monotonic()
                continue
            due = (max(due + period, time.monotonic() - period) if self.clock.fast
                   else due + n * period)
            for c in clients:
                for frame in frames:
                    self._send_frame(c, frame)

    def _next_frame(self, when: float) -> Frame:
        """The next frame; on the real-time clock stamped as made at ``when`` (monotonic s),
        as UTC. On the fast clock frames are stamped ``1 / rate_hz`` apart."""
        k = self._served
        t = (self._t0_utc + k / self.rate_hz if self.clock.fast
             else self._t0_utc + (when - self._t0_mono))
        sec, frac = wire.timestamp_parts(t)
        frame = self._frames.frame(k, (sec << 32) | frac)
        self._served += 1
        return frame

    def _send_frame(self, c: _Client, frame: Frame) -> None:
        f = self.faults
        if f.garbage_after_frames and c.frames == f.garbage_after_frames:
            c.send(_GARBAGE)
        c.send(frame.wire(c.version))
        c.frames += 1
        if f.disconnect_after_frames and c.frames >= f.disconnect_after_frames:
            log.info("OpenIGTLink mock: closing a client after %d frames (fault)", c.frames)
            c.drop()

    # --- a client's messages -----------------------------------------------------------------
    def _serve_conn(self, conn: socket.socket) -> None:
        conn.settimeout(_SEND_TIMEOUT_S)
        client = _Client(conn, self.header_version)
        with self._lock:
            self._clients.add(client)
        buf = bytearray()
        try:
            while not self._stop.is_set() and not client.closed:
                ready, _, _ = select.select([conn], [], [], _POLL_S)
                if not ready:
                    continue
                data = conn.recv(4096)
                if not data:
                    return
                buf += data
                if not self._answer(client, buf):
                    return
        finally:
            client.closed = True
            with self._lock:
                self._clients.discard(client)

    def _answer(self, client: _Client, buf: bytearray) -> bool:
        """Handle the complete messages in ``buf`` as PlusServer does: the client's header
        version is raised to the highest it sent (at most 2); ``GET_STATUS`` is answered
        ``STATUS`` OK; anything else is skipped. False for bytes that are not OpenIGTLink
        (the connection is then closed)."""
        while len(buf) >= wire.HEADER_SIZE:
            try:
                h = wire.parse_header(bytes(buf[:wire.HEADER_SIZE]))
            except ProtocolError as e:
                log.info("OpenIGTLink mock: closing a client that sent %s", e)
                return False
            end = wire.HEADER_SIZE + h.body_size
            if len(buf) < end:
                return True
            del buf[:end]
            client.version = max(client.version, min(h.version, 2))
            if h.type == "GET_STATUS":
                client.send(wire.encode("STATUS", "", STATUS_OK, version=client.version))
        return True
