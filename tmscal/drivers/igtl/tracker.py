"""An OpenIGTLink tracker: the TRANSFORM messages of a PlusServer (or any OpenIGTLink
source) as :class:`~tmscal.drivers.base.TrackerFrame` s, which gives tmscal every tracker
PLUS supports (Atracsys, OptiTrack, Claron, NDI Aurora, …).

Session: a TCP connection to ``host:port`` (PlusServer's default 18944); one ``GET_STATUS``
with header version 2 (PlusServer answers every client with the highest header version the
client has sent, so its TRANSFORMs then carry the version-2 metadata ``TransformStatus``;
``ask_metadata=False`` sends nothing); then a reader thread takes every message the source
streams, as fast as it comes, so the source never waits on us (PlusServer drops a client it
cannot send to within its send timeout). TRANSFORMs become frames (:mod:`.frames`: a frame is
the transforms of one timestamp; stale, missing and invalid tools are
``ToolState(pose=None, missing=True)``); other messages (``STATUS`` keep-alives, IMAGEs,
command replies) are skipped. Each TRANSFORM's CRC and layout are checked (:mod:`.wire`).

:meth:`IGTLTracker.read` returns the newest frame not returned before, waiting for it when
polled faster than frames come (so a caller polling in a loop does not spin). Poses are the
TRANSFORMs' matrices, keyed by OUR tool names: a device name ``MarkerToTracker`` is PLUS's
tracker_from_marker, 4×4, mm (PLUS works in mm; sent as float32, so a translation of 1.5 m
carries about 0.1 µm of rounding).

Errors (each names ``igtl host:port``): refused, reset or closed connections are
``ConnectionLost``; no connection within ``timeout_s`` and no frame for ``timeout_s`` are
``DeviceTimeout``; bytes that are not OpenIGTLink, a CRC mismatch and a malformed TRANSFORM are
``ProtocolError``. An error ends the reader; every later ``read()`` raises it until
``close()`` and ``open()`` (a reconnect). Device facts relied on: docs/devices.md,
"OpenIGTLink tracker (PlusServer)".
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections import Counter
from collections.abc import Mapping
from typing import Any

from ...errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError
from ...net import connect_problem
from ...timing import Deadline
from ..base import Tracker, TrackerFrame
from . import wire
from .frames import FrameAssembler, transform_status
from .settings import DEFAULT_PORT, IGTLSettings

log = logging.getLogger(__name__)

__all__ = ["IGTLTracker", "DEFAULT_PORT"]

#: the options' defaults, declared once in IGTLSettings.OPTIONS
_OPT = IGTLSettings.defaults()
_RECV_BYTES = 1 << 16
#: how often the reader looks at its stop flag while the source is quiet (s)
_POLL_S = 0.1


class IGTLTracker(Tracker):
    """An OpenIGTLink source of TRANSFORM messages as a tracker.

    Parameters:

    * ``host``, ``port``: the source (PlusServer: its ``ListeningPort``, 18944 by default).
    * ``tools``: our tool name → the device name of its TRANSFORM (e.g. ``{"marker":
      "MarkerToTracker", "probe": "ProbeToTracker"}``; PlusServer's names are the transform
      names of its ``DefaultClientInfo``, cut to their first 20 characters).
    * ``frame_rate_hz``: the source's frame rate (Hz), for callers.
    * ``timeout_s``: longest wait for the connection and for a new frame (s).
    * ``ask_metadata``: send one version-2 ``GET_STATUS`` after connecting (see the module
      docstring).
    """

    name = "igtl"

    def __init__(self, host: str, tools: Mapping[str, str], *, port: int = DEFAULT_PORT,
                 frame_rate_hz: float = 60.0, timeout_s: float = _OPT["timeout_s"],
                 ask_metadata: bool = _OPT["ask_metadata"]) -> None:
        if not isinstance(host, str) or not host:
            raise ValueError("IGTLTracker: host must be a non-empty address")
        if isinstance(port, bool) or not isinstance(port, int) or not 0 < port < 65536:
            raise ValueError(f"IGTLTracker: port must be a TCP port 1…65535, got {port!r}")
        if not tools:
            raise ValueError("IGTLTracker needs at least one tool")
        for tool, dev in tools.items():
            if not isinstance(dev, str) or not dev \
                    or len(dev.encode("utf-8")) > wire.MAX_NAME_BYTES:
                raise ValueError(f"IGTLTracker: tool {tool!r}: device name {dev!r} must be "
                                 f"1…{wire.MAX_NAME_BYTES} bytes")
        if len(set(tools.values())) != len(tools):
            raise ValueError(f"IGTLTracker: two tools share one device name: {dict(tools)}")
        o = IGTLSettings.check_options("IGTLTracker", timeout_s=timeout_s,
                                       ask_metadata=ask_metadata)
        super().__init__(list(tools), frame_rate_hz)
        self.host, self.port = host, port
        self.device_names = dict(tools)
        self.timeout_s: float = o["timeout_s"]
        self.ask_metadata: bool = o["ask_metadata"]
        self._where = f"{self.name} {f'[{host}]' if ':' in host else host}:{port}"
        self._cond = threading.Condition()
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._latest: TrackerFrame | None = None
        self._returned: int | None = None  # the frame number read() returned last
        self._failure: DeviceError | None = None
        self._next_frame = 0  # frame numbers never repeat over reconnects
        self._seen: Counter[str] = Counter()  # message types received, this connection
        self._first = threading.Event()  # the connection's first TRANSFORM (or failure)
        #: what the source has shown over the driver's life (identity; kept over reconnects)
        self._header_version: int | None = None
        self._transform_status = False
        self._status_logged: dict[str, str | None] = {}

    # --- lifecycle ---------------------------------------------------------------------------
    def _open(self) -> None:
        self._stop.clear()
        with self._cond:
            self._latest, self._failure, self._returned = None, None, None
            self._seen.clear()
        self._first.clear()
        self._status_logged.clear()
        self._sock = self._connect()
        if self.ask_metadata:
            try:
                self._sock.sendall(wire.encode("GET_STATUS", version=2))
            except OSError as e:
                raise ConnectionLost(f"{self._where}: sending GET_STATUS failed ({e})",
                                     device=self.name) from e
        self._thread = threading.Thread(target=self._reader, args=(self._sock,), daemon=True,
                                        name=f"igtl-reader-{self.host}:{self.port}")
        self._thread.start()
        if not self._first.wait(self.timeout_s):
            log.warning("%s: no TRANSFORM within %g s of connecting (are %s among the "
                        "source's transform names, and is any of them valid?)", self._where,
                        self.timeout_s, sorted(self.device_names.values()))
        with self._cond:
            if self._failure is not None:
                raise self._failure
        log.info("%s: connected, tools %s", self._where, self.device_names)

    def _connect(self) -> socket.socket:
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except OSError as e:  # refused, no answer, unreachable, a name that does not resolve
            why = connect_problem(e, self.host, self.port, "tracker.host, tracker.port",
                                  self.timeout_s, service="PlusServer or another "
                                  "OpenIGTLink server")
            cls = DeviceTimeout if isinstance(e, TimeoutError) else ConnectionLost
            raise cls(f"{self._where}: {why or e}", device=self.name) from e
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(_POLL_S)
        return sock

    def _close(self) -> None:
        self._stop.set()
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        if sock is not None:
            sock.close()

    def identity(self) -> dict[str, Any]:
        """{"driver", "host", "port", "tools" (tool → device name), "header_version" (the
        highest of the source's TRANSFORMs so far; None before the first), "transform_status"
        (whether they carry PlusServer's ``TransformStatus``)}. OpenIGTLink has no identity
        query; ``open()`` waits up to ``timeout_s`` for the first TRANSFORM so that these are
        known, and they are kept over reconnects. :meth:`received` counts what arrived."""
        with self._cond:
            return {"driver": self.name, "host": self.host, "port": self.port,
                    "tools": dict(self.device_names), "header_version": self._header_version,
                    "transform_status": self._transform_status}

    def received(self) -> dict[str, int]:
        """Message type → how many arrived on this connection (a PlusServer shows as
        ``STATUS`` keep-alives beside the TRANSFORMs)."""
        with self._cond:
            return dict(sorted(self._seen.items()))

    # --- reading -----------------------------------------------------------------------------
    def _read(self) -> TrackerFrame:
        deadline = Deadline(self.timeout_s)
        with self._cond:
            while True:
                if self._failure is not None:
                    raise self._failure
                fr = self._latest
                if fr is not None and fr.frame != self._returned:
                    self._returned = fr.frame
                    return fr
                left = deadline.remaining()
                if left <= 0:
                    raise DeviceTimeout(self._no_frame_text(fr), device=self.name)
                self._cond.wait(left)

    def _no_frame_text(self, last: TrackerFrame | None) -> str:
        seen = ", ".join(f"{k}×{n}" for k, n in sorted(self._seen.items())) or "nothing"
        since = ("no frame yet" if last is None else
                 f"last frame {last.frame} {time.monotonic() - last.host_time:.1f} s ago")
        return (f"{self._where}: no new TRANSFORM frame within {self.timeout_s:g} s ({since}; "
                f"received so far: {seen}; expected device names "
                f"{sorted(self.device_names.values())})")

    def _reader(self, sock: socket.socket) -> None:
        """The reader thread: messages from ``sock`` into frames until stopped or failed."""
        frames = FrameAssembler(self.device_names, first_frame=self._next_frame)
        buf = bytearray()
        try:
            while not self._stop.is_set():
                try:
                    chunk = sock.recv(_RECV_BYTES)
                except TimeoutError:
                    continue
                except OSError as e:
                    raise ConnectionLost(f"{self._where}: connection lost ({e})",
                                         device=self.name) from e
                if not chunk:
                    raise ConnectionLost(f"{self._where}: the source closed the connection",
                                         device=self.name)
                buf += chunk
                self._take_messages(buf, frames, time.monotonic())
        except DeviceError as e:
            if not self._stop.is_set():
                log.warning("%s", e)
                with self._cond:
                    self._failure = e
                    self._cond.notify_all()
        finally:
            self._first.set()
            self._next_frame = frames.next_frame

    def _take_messages(self, buf: bytearray, frames: FrameAssembler, arrival: float) -> None:
        """Every complete message at the start of ``buf``, removed from it."""
        pos = 0
        try:
            while len(buf) - pos >= wire.HEADER_SIZE:
                header = self._header(buf, pos)
                end = pos + wire.HEADER_SIZE + header.body_size
                if len(buf) < end:
                    return
                body_at, pos = pos + wire.HEADER_SIZE, end
                with self._cond:
                    self._seen[header.type] += 1
                if header.type == "TRANSFORM":
                    self._take_transform(header, bytes(buf[body_at:end]), frames, arrival)
        finally:
            del buf[:pos]

    def _header(self, buf: bytearray, pos: int) -> wire.Header:
        try:
            return wire.parse_header(bytes(buf[pos:pos + wire.HEADER_SIZE]))
        except ProtocolError as e:
            raise self._protocol_error(e) from None

    def _take_transform(self, header: wire.Header, body: bytes, frames: FrameAssembler,
                        arrival: float) -> None:
        try:
            t = wire.decode_transform(header, body)
        except ProtocolError as e:
            raise self._protocol_error(e) from None
        self._note(t)
        delivered = frames.feed(t, arrival)
        if delivered:
            with self._cond:
                self._latest = delivered[-1]
                self._cond.notify_all()

    def _protocol_error(self, e: ProtocolError) -> ProtocolError:
        return ProtocolError(f"{self._where}: {e}", code=e.code, text=e.text, device=self.name)

    def _note(self, t: wire.Transform) -> None:
        """Remember what the source sends (identity) and log a tool's status when it
        changes (not every frame)."""
        with self._cond:
            self._header_version = max(self._header_version or 0, t.version)
            self._transform_status |= "TransformStatus" in t.metadata
        self._first.set()
        status = transform_status(t)
        if t.device in self.device_names.values() \
                and self._status_logged.get(t.device, "OK") != (status or "OK"):
            log.info("%s: %s status %s", self._where, t.device, status or "OK")
        self._status_logged[t.device] = status or "OK"
