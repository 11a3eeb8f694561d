"""Live OpenIGTLink streaming of the tracked coil through a calibration (``tmscal stream``).

An OpenIGTLink server (messages packed by the ``pyigtl`` package) that navigation programs
such as 3D Slicer's OpenIGTLinkIF module connect to as clients, several at once, each with its
own limits (:class:`StreamServer`). For every distinct tracker frame it sends one
TRANSFORM message per name in :data:`TRANSFORMS` (docs/streaming.md):

==================== ============================================================
device name          transform (4×4, mm; Slicer's "FromToTo" naming: maps From into To)
==================== ============================================================
CoilToRobotBase      robot base ← coil centre: the coil pose the robot's controller
                     must be told, A_cmd · Y (Z · coil without an arm)
CoilToTracker        tracker ← coil centre: B · X⁻¹ · Y, from the marker
ProbeToTracker       tracker ← probe: C, as the tracker measures it
MarkerToTracker      tracker ← coil marker: B, as the tracker measures it
TrackerToRobotBase   robot base ← tracker: Z of the calibration
==================== ============================================================

The coil comes from one body for the whole stream (:func:`coil_source`): from the marker,
B · X⁻¹ · Y with the calibration's marker ← coil (``Calibration.marker_from_coil``, the
exported X and Y), whenever the config tracks a marker and the calibration has a coil (Y);
the probe is then only a cross-check, sent as ProbeToTracker, and the difference between the
coil it measures and the marker's (:func:`coil_difference`) is counted in
:class:`StreamStats`. Without a marker tool, or with a marker-only calibration (no Y), the
coil is the probe as measured (CoilToTracker = C), as a probe-only rig needs; with neither,
no coil is sent.

Z is the calibration's orthonormal base_from_tracker (``Calibration.exported()``, the ``Z`` of
``tmscal solve -o`` and of every export: docs/exports.md, "Which matrices leave tmscal"). With a
tracker distortion in the calibration (the ``ml`` solver), CoilToRobotBase is Z applied to the
undistorted coil pose (the marker or probe pose undistorted, then the coil on it), as the robot
would place the coil (``Calibration.placement``); the tracker poses are sent as measured. With
an identified arm in the calibration (``tmscal solve --kinematics``, docs/kinematics.md),
CoilToRobotBase is A_cmd · Y with A_cmd = ``Calibration.flange_command``: the flange pose the
controller's own (nominal) kinematics must be told so that the real arm puts the coil where
it is (inverse kinematics on the identified arm, forward on the nominal one), times the coil's
Y, i.e. the coil pose to send to a controller whose tool frame is Y. Without an arm that is
Z · coil (the placement rule; exactly for orthonormal matrices), which is what is sent. A coil
pose the identified arm cannot reach gets no CoilToRobotBase in that frame.

A body that is missing or (partly) out of the tracker's volume in a frame is not sent for that
frame, nor what is derived from it, as PlusServer does by default: the client keeps the last
pose it received (docs/streaming.md says how to notice).

OpenIGTLink carries float32: about 1e-4 mm at 1,500 mm from the tracker.

This module has no CLI: :mod:`tmscal.cli.stream` parses the options and shows the status.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import socket
import socketserver
import struct
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyigtl

from .calib import Calibration
from .drivers.base import Tracker, TrackerFrame
from .drivers.igtl.wire import STATUS_CODES, StatusMessage
from .errors import CalibrationError
from .geometry import angle_between

log = logging.getLogger(__name__)

__all__ = ["TRANSFORMS", "MAX_NAME_BYTES", "DEFAULT_PORT", "frame_transforms", "StreamServer",
           "StreamStats", "CrossCheck", "stream_frames", "coil_source", "coil_difference",
           "MAX_CLIENTS", "QUEUE_FRAMES", "STALL_S", "MAX_BODY_BYTES", "STATUS_CODES"]

#: OpenIGTLink's registered TCP port, the default of Slicer's OpenIGTLinkIF and PlusServer
DEFAULT_PORT = 18944

#: the OpenIGTLink header's device name field is 20 bytes
MAX_NAME_BYTES = 20

#: the OpenIGTLink header (version 1 and 2): 58 bytes
HEADER_BYTES = 58

#: per-client limits (docs/streaming.md): clients served at once; frames queued for a client
#: that reads more slowly than the tracker sends (then its oldest are dropped); seconds a
#: client may take no data while frames wait before it is disconnected; the largest message
#: body a client may send (its header announcing more closes the connection); the kernel
#: send buffer asked for each client (about 150 frames: a slow client lags by little)
MAX_CLIENTS = 8
QUEUE_FRAMES = 64
STALL_S = 10.0
MAX_BODY_BYTES = 1 << 20
SOCKET_BUFFER_BYTES = 64 * 1024

_POLL_S = 0.05

#: device name → what it is (frames and formula); the order in which each frame is sent
TRANSFORMS: dict[str, str] = {
    "CoilToRobotBase": "robot base ← coil centre: the coil pose to command, A_cmd · Y "
                       "(Z · coil without an identified arm)",
    "CoilToTracker": "tracker ← coil centre: B · X⁻¹ · Y from the marker (C from the probe "
                     "without a marker tool or without Y)",
    "ProbeToTracker": "tracker ← probe: C as the tracker measures it",
    "MarkerToTracker": "tracker ← coil marker: B as the tracker measures it",
    "TrackerToRobotBase": "robot base ← tracker: Z of the calibration",
}


def coil_source(tools: Iterable[str], cal: Calibration, marker: str = "marker",
                probe: str = "probe") -> str | None:
    """Which body the coil comes from for a whole stream, given the tracker's tool names:
    "marker" (B · X⁻¹ · Y) when the ``marker`` tool is tracked and the calibration has a
    coil (Y); else "probe" (C as measured) when the ``probe`` tool is tracked; else None (no
    coil can be sent: a marker-only calibration without a probe)."""
    names = set(tools)
    if marker in names and cal.Y is not None:
        return "marker"
    if probe in names:
        return "probe"
    return None


def coil_difference(measured: np.ndarray, derived: np.ndarray) -> tuple[float, float]:
    """(mm, degrees) between two coil poses (tracker ← coil, 4×4 mm): the distance of their
    origins and the angle of the rotation between them; for the probe-measured coil C and
    the marker-derived B · X⁻¹ · Y, the stream's cross-check."""
    mm = float(np.linalg.norm(measured[:3, 3] - derived[:3, 3]))
    return mm, float(np.degrees(angle_between(measured, derived)))


def frame_transforms(frame: TrackerFrame, cal: Calibration, marker: str = "marker",
                     probe: str = "probe", coil_from: str | None = "marker"
                     ) -> dict[str, np.ndarray]:
    """The transforms of :data:`TRANSFORMS` for one tracker frame (4×4 float64, mm), by
    device name. TrackerToRobotBase is always there; MarkerToTracker only when the ``marker``
    tool is usable in the frame (present, inside the volume), ProbeToTracker only when the
    ``probe`` tool is. CoilToTracker and CoilToRobotBase come from ``coil_from``
    (:func:`coil_source`): "marker", the coil B · X⁻¹ · Y whenever the marker is usable
    (CalibrationError for a marker-only calibration); "probe", C whenever the probe is;
    None, never. With an identified arm in the calibration, CoilToRobotBase only when that
    arm can reach the coil pose."""
    if coil_from not in ("marker", "probe", None):
        raise ValueError(f"coil_from must be 'marker', 'probe' or None, got {coil_from!r}")
    Z = np.asarray(cal.exported()["Z"], dtype=float)
    offset = cal.marker_from_coil() if coil_from == "marker" else None
    out: dict[str, np.ndarray] = {}
    C = _usable(frame, probe)
    B = _usable(frame, marker)
    if offset is not None and B is not None:
        coil, pose, body = B @ offset, B, "marker"
    elif coil_from == "probe" and C is not None:
        coil, pose, body = C, C, "probe"
    else:
        coil, pose, body = None, None, ""
    if coil is not None and pose is not None:
        command = _coil_command(cal, pose, body)
        if command is not None:
            out["CoilToRobotBase"] = command
        out["CoilToTracker"] = coil
    if C is not None:
        out["ProbeToTracker"] = C
    if B is not None:
        out["MarkerToTracker"] = B
    out["TrackerToRobotBase"] = Z
    return out


def _coil_command(cal: Calibration, N: np.ndarray, body: str) -> np.ndarray | None:
    """robot base ← coil (4×4 mm) to command for the tracker pose N of ``body`` ("probe":
    the coil's own pose; "marker": the coil on it): Z · coil' (coil' undistorted when the
    calibration says so; ``Calibration.placement``) without an identified arm; with one,
    A_cmd · Y (``Calibration.flange_command``), None when the arm cannot reach it."""
    if cal.arm is None or cal.Y is None:
        targets, _, _ = cal.placement(N[None], body)  # undistorted when the calibration says so
        return np.asarray(cal.exported()["Z"], dtype=float) @ targets[0]
    try:
        return (cal.flange_command(N[None], body=body)[0]
                @ np.asarray(cal.exported()["Y"], dtype=float))
    except CalibrationError as e:
        log.debug("no CoilToRobotBase in this frame: %s", e)
        return None


def _usable(frame: TrackerFrame, tool: str) -> np.ndarray | None:
    st = frame.tools.get(tool)
    if st is None or not st.usable:
        return None
    return np.asarray(st.pose, dtype=float)


def _family(host: str) -> socket.AddressFamily:
    """AF_INET6 for a host that has only IPv6 addresses (``::1``), else AF_INET."""
    try:
        infos = socket.getaddrinfo(host, None, socket.AF_UNSPEC, socket.SOCK_STREAM)
    except OSError:
        return socket.AF_INET  # bind() then says what is wrong with the host
    fams = {i[0] for i in infos}
    return socket.AF_INET if socket.AF_INET in fams or not fams else socket.AF_INET6


class _Refused(Exception):
    """A client broke a per-client limit; its connection is closed (the message says why)."""


class _Client:
    """One connected client's state, shared by its handler thread and the stream loop: a
    bounded queue of frames to send (each the packed TRANSFORM messages of one tracker
    frame; the oldest dropped when it is full), when it last accepted data, and a pipe that
    wakes its handler when a frame is queued (or the server stops)."""

    def __init__(self, peer: str, queue_frames: int) -> None:
        self.peer = peer
        self.queue: deque[bytes] = deque(maxlen=queue_frames)
        self.lock = threading.Lock()
        self.dropped = 0
        self.progress = time.monotonic()
        self.closed = False
        self.wake_r, self.wake_w = os.pipe()
        for fd in (self.wake_r, self.wake_w):
            os.set_blocking(fd, False)

    def offer(self, frame: bytes) -> None:
        with self.lock:
            if len(self.queue) == self.queue.maxlen:
                self.dropped += 1  # the deque drops the oldest frame
            self.queue.append(frame)
            self._wake()

    def wake(self) -> None:
        with self.lock:
            self._wake()

    def _wake(self) -> None:  # under the lock: never a write to a closed (reused) fd
        if not self.closed:
            with contextlib.suppress(OSError):  # the pipe is full: a wake-up is pending
                os.write(self.wake_w, b"!")

    def woken(self) -> None:
        with contextlib.suppress(OSError):
            os.read(self.wake_r, 4096)

    def close(self) -> None:
        with self.lock:
            self.closed = True
            for fd in (self.wake_r, self.wake_w):
                with contextlib.suppress(OSError):
                    os.close(fd)

    def take(self) -> bytes | None:
        with self.lock:
            return self.queue.popleft() if self.queue else None

    def waiting(self) -> bool:
        with self.lock:
            return bool(self.queue)


class _Handler(socketserver.BaseRequestHandler):
    """One connected client, in its own thread: sends its queued frames as fast as it takes
    them (never blocking: select and non-blocking sends), and reads and drops what it
    sends, refusing a message whose header announces a body above the server's
    ``max_body_bytes`` before reading any of it. A client that accepts nothing for
    ``stall_s`` seconds while frames wait is disconnected. A client that hangs up, sends
    garbage or breaks a limit ends its own connection only, with one log line."""

    def handle(self) -> None:
        srv: StreamServer = self.server  # type: ignore[assignment]
        sock: socket.socket = self.request
        client = srv._claim(self.client_address)
        peer = client.peer
        sock.setblocking(False)
        with contextlib.suppress(OSError):  # a small kernel queue: a slow client lags less
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, srv.socket_buffer_bytes)
        log.info("OpenIGTLink client %s connected", peer)
        why = "disconnected"
        try:
            self._serve(srv, sock, client)
        except _Refused as e:
            why = str(e)
            log.warning("OpenIGTLink client %s: %s; connection closed", peer, e)
        except Exception as e:  # a peer on the network: any failure ends its connection
            why = f"disconnected ({e})"
        finally:
            srv._remove(client)
            log.info("OpenIGTLink client %s %s (%d frames dropped for it)", peer, why,
                     client.dropped)

    def _serve(self, srv: StreamServer, sock: socket.socket, client: _Client) -> None:
        pending = b""
        incoming = _Incoming(srv.max_body_bytes)
        while not srv._stopping.is_set():
            if not pending:
                pending = client.take() or b""
                if not pending:
                    client.progress = time.monotonic()  # nothing waits for it
            watched: list[socket.socket | int] = [sock, client.wake_r]
            r, w, _ = select.select(watched, [sock] if pending else [], [], _POLL_S)
            if client.wake_r in r:
                client.woken()
            if sock in r:
                data = sock.recv(65536)
                if not data:
                    return  # the client hung up
                incoming.feed(data)
            if w and pending:
                try:
                    n = sock.send(pending)
                except BlockingIOError:
                    n = 0
                if n:
                    pending = pending[n:]
                    client.progress = time.monotonic()
            if pending and time.monotonic() - client.progress > srv.stall_s:
                raise _Refused(f"took no data for {srv.stall_s:g} s (not reading?)")


class _Incoming:
    """What a client sends, parsed only as far as the OpenIGTLink header (58 bytes; the
    body size is the big-endian uint64 at byte 42) and dropped: a body announced above
    ``max_body`` bytes is refused at its header, before any of it is read or kept."""

    def __init__(self, max_body: int) -> None:
        self.max_body = max_body
        self.head = b""
        self.skip = 0  # body bytes still to drop

    def feed(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            if self.skip:
                n = min(self.skip, len(view))
                self.skip -= n
                view = view[n:]
                continue
            need = HEADER_BYTES - len(self.head)
            self.head += bytes(view[:need])
            view = view[need:]
            if len(self.head) == HEADER_BYTES:
                (size,) = struct.unpack_from(">Q", self.head, 42)
                if size > self.max_body:
                    raise _Refused(f"sent a message announcing a {size:,}-byte body (the "
                                   f"limit is {self.max_body:,})")
                self.skip, self.head = size, b""


class StreamServer(socketserver.ThreadingTCPServer):
    """An OpenIGTLink server bound to ``host`` that serves several clients at once, each in
    its own thread with its own limits (docs/streaming.md): at most ``max_clients`` (more are
    closed at once, with a log line); per client a queue of ``queue_frames`` frames (when a
    client reads more slowly than frames come, its oldest frames are dropped, not the other
    clients'), a kernel send buffer of about ``socket_buffer_bytes``, disconnection after
    ``stall_s`` seconds in which it took no data while frames waited, and disconnection
    when a message it sends announces a body above ``max_body_bytes`` (refused at its
    header, never read). ``port`` 0 picks a free port; ``port`` and ``host`` are then what
    was bound. Whether ``host`` may be off loopback is the caller's decision
    (:func:`tmscal.net.is_loopback`). Installs no signal handlers (the caller owns Ctrl-C).
    Use as a context manager, or ``start()`` and ``stop()``."""

    allow_reuse_address = True
    daemon_threads = True

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *,
                 max_clients: int = MAX_CLIENTS, queue_frames: int = QUEUE_FRAMES,
                 stall_s: float = STALL_S, max_body_bytes: int = MAX_BODY_BYTES,
                 socket_buffer_bytes: int = SOCKET_BUFFER_BYTES) -> None:
        if max_clients < 1 or queue_frames < 1 or stall_s <= 0 or max_body_bytes < 0:
            raise ValueError("max_clients and queue_frames must be ≥ 1, stall_s > 0 and "
                             "max_body_bytes ≥ 0")
        self.address_family = _family(host)
        super().__init__((host, port), _Handler)
        self.host, self.port = str(self.server_address[0]), int(self.server_address[1])
        self.max_clients, self.queue_frames = max_clients, queue_frames
        self.stall_s, self.max_body_bytes = stall_s, max_body_bytes
        self.socket_buffer_bytes = socket_buffer_bytes
        self.clients = 0  # connections that have ended
        self.refused = 0  # connections closed at once: too many clients
        self._dropped_ended = 0
        self._active: dict[Any, _Client] = {}  # by client address
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._latched: bytes | None = None  # the last STATUS, sent to every new client

    # --- the clients ---------------------------------------------------------------------------

    def verify_request(self, request: Any, client_address: Any) -> bool:
        """Admit a connection (its slot taken here, in the accepting thread, so that no
        burst of connections gets past the limit), or refuse (close) one beyond
        ``max_clients``."""
        peer = f"{client_address[0]}:{client_address[1]}"
        with self._lock:
            full = len(self._active) >= self.max_clients or self._stopping.is_set()
            if full:
                self.refused += 1
            else:
                c = _Client(peer, self.queue_frames)
                if self._latched is not None:
                    c.offer(self._latched)
                self._active[client_address] = c
        if full:
            log.warning("OpenIGTLink client %s refused: %d clients already connected (the "
                        "limit)", peer, self.max_clients)
        return not full

    def _claim(self, client_address: Any) -> _Client:
        with self._lock:
            return self._active[client_address]

    def _remove(self, client: _Client) -> None:
        with self._lock:
            self._active = {k: c for k, c in self._active.items() if c is not client}
            self.clients += 1
            self._dropped_ended += client.dropped
        client.close()

    def _snapshot(self) -> list[_Client]:
        with self._lock:
            return list(self._active.values())

    @property
    def peers(self) -> list[str]:
        """The connected clients, "host:port" each, in the order they connected."""
        return [c.peer for c in self._snapshot()]

    @property
    def peer(self) -> str | None:
        """The connected clients as one string ("host:port, host:port"), None without."""
        return ", ".join(self.peers) or None

    @property
    def dropped(self) -> int:
        """Frames dropped so far for slow clients (connected now or gone), summed over
        them."""
        with self._lock:
            return self._dropped_ended + sum(c.dropped for c in self._active.values())

    def is_connected(self) -> bool:
        """True while at least one client is connected."""
        return bool(self._snapshot())

    # --- running -------------------------------------------------------------------------------

    def start(self) -> None:
        """Accept clients in a background thread."""
        self._thread = threading.Thread(target=self.serve_forever, name="igtl-server",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Disconnect every client and close the listening socket (safe twice)."""
        self._stopping.set()
        for c in self._snapshot():
            c.wake()
        if self._thread is not None:
            self.shutdown()
            self._thread.join(5.0)
            self._thread = None
        self.server_close()  # joins the client threads, which end at the wake-up

    def __enter__(self) -> StreamServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def send_status(self, code: int, error_name: str, text: str, *,
                    device_name: str = "TMSCalMonitor", subcode: int = 0,
                    timestamp: float | None = None) -> int:
        """Queue one STATUS message (:class:`StatusMessage`: ``code`` of
        :data:`STATUS_CODES`, ``error_name`` up to 20 bytes, ``text`` the status string) for
        every connected client, and keep it: a client that connects later gets the last
        status first. Returns the number of clients it was queued for."""
        if len(device_name.encode("utf-8")) > MAX_NAME_BYTES:
            raise ValueError(f"device name {device_name!r} is longer than {MAX_NAME_BYTES} "
                             "bytes")
        msg = StatusMessage(code, subcode, error_name, text, timestamp=timestamp,
                            device_name=device_name).pack()
        with self._lock:
            self._latched = msg
            clients = list(self._active.values())
        for c in clients:
            c.offer(msg)
        return len(clients)

    def send_transforms(self, transforms: Mapping[str, np.ndarray], timestamp: float) -> int:
        """Queue one TRANSFORM message per item (device name → 4×4 mm), as one frame, for
        every connected client; nothing is queued without a client. Returns the number of
        messages in the frame (0 without a client)."""
        clients = self._snapshot()
        if not clients:
            return 0
        parts = []
        for name, M in transforms.items():
            if len(name.encode("utf-8")) > MAX_NAME_BYTES:
                raise ValueError(f"device name {name!r} is longer than {MAX_NAME_BYTES} bytes")
            msg = pyigtl.TransformMessage(np.asarray(M, dtype=float), timestamp=timestamp,
                                          device_name=name)
            parts.append(msg.pack())
        frame = b"".join(parts)
        for c in clients:
            c.offer(frame)
        return len(parts)


@dataclass
class CrossCheck:
    """The difference between the coil the probe measures (C) and the coil derived from the
    marker (B · X⁻¹ · Y), over the frames that saw both (:func:`coil_difference`): ``n``
    frames, the ``last`` frame's (mm, degrees), and their means and maxima. The mock's noise
    when the calibration holds; a wrong Y, or a marker or probe that moved on the coil since
    the calibration, shows as the offset it is."""

    n: int = 0
    last: tuple[float, float] | None = None
    max_mm: float = 0.0
    max_deg: float = 0.0
    _sum_mm: float = field(default=0.0, repr=False)
    _sum_deg: float = field(default=0.0, repr=False)

    def add(self, mm: float, deg: float) -> None:
        self.n += 1
        self.last = (mm, deg)
        self._sum_mm += mm
        self._sum_deg += deg
        self.max_mm = max(self.max_mm, mm)
        self.max_deg = max(self.max_deg, deg)

    @property
    def mean_mm(self) -> float | None:
        return self._sum_mm / self.n if self.n else None

    @property
    def mean_deg(self) -> float | None:
        return self._sum_deg / self.n if self.n else None


@dataclass
class StreamStats:
    """What a stream has done so far: distinct tracker ``frames`` read, frames ``sent`` to a
    client, TRANSFORM ``messages`` queued, per tool the frames it was not usable in
    (``unseen``), the measured ``rate_hz`` (tracker frames per second over the last second),
    the connected client (``peer``, "host:port", or None), the body the coil comes from
    (``coil_from``: "marker", "probe" or None; :func:`coil_source`) and, when it is the
    marker, the probe's ``crosscheck`` over every frame read that saw both tools."""

    frames: int = 0
    sent: int = 0
    messages: int = 0
    unseen: Counter[str] = field(default_factory=Counter)
    rate_hz: float | None = None
    peer: str | None = None
    coil_from: str | None = None
    crosscheck: CrossCheck = field(default_factory=CrossCheck)
    _recent: list[float] = field(default_factory=list, repr=False)

    def _tick(self, t: float) -> None:
        self._recent.append(t)
        while len(self._recent) > 2 and t - self._recent[0] > 1.0:
            self._recent.pop(0)
        span = self._recent[-1] - self._recent[0]
        self.rate_hz = (len(self._recent) - 1) / span if span > 0 else None


def stream_frames(tracker: Tracker, cal: Calibration, server: StreamServer, *,
                  rate_hz: float | None = None, frames: int | None = None,
                  stop: Callable[[], bool] = lambda: False,
                  on_frame: Callable[[StreamStats], None] | None = None,
                  stall_s: float = 5.0) -> StreamStats:
    """Read each distinct frame of an open ``tracker`` and send its :func:`frame_transforms`
    to the server's client, until ``stop()`` is true (checked after every frame) or
    ``frames`` distinct frames were read. The coil comes from :func:`coil_source` of the
    tracker's tools, for the whole stream; when that is the marker, every frame read in
    which the probe is usable too adds the probe's difference to ``crosscheck``.
    ``rate_hz`` sends at most that many frames a second (the others are read and dropped);
    None sends every frame (the tracker's frame rate). Each message carries the frame's
    arrival time (seconds since 1970). ``on_frame`` gets the running :class:`StreamStats`
    after every frame. A tracker without a new frame for ``stall_s`` seconds raises
    DeviceTimeout (the tracker's own errors pass through)."""
    stats = StreamStats(coil_from=coil_source(tracker.tools, cal))
    offset = cal.marker_from_coil() if stats.coil_from == "marker" else None
    period = 0.0 if rate_hz is None else 1.0 / rate_hz
    last_sent = -np.inf
    it = tracker.distinct_frames(frames, stall_s=stall_s)
    try:
        for fr in it:
            stats.frames += 1
            stats._tick(fr.host_time)
            for tool in tracker.tools:
                st = fr.tools.get(tool)
                if st is None or not st.usable:
                    stats.unseen[tool] += 1
            if offset is not None:
                B, C = _usable(fr, "marker"), _usable(fr, "probe")
                if B is not None and C is not None:
                    stats.crosscheck.add(*coil_difference(C, B @ offset))
            stats.peer = server.peer
            if fr.host_time - last_sent >= period:
                stamp = time.time() - (time.monotonic() - fr.host_time)
                n = server.send_transforms(frame_transforms(fr, cal, coil_from=stats.coil_from),
                                           stamp)
                if n:
                    last_sent = fr.host_time
                    stats.sent += 1
                    stats.messages += n
            if on_frame is not None:
                on_frame(stats)
            if stop():
                break
    finally:
        it.close()
    return stats
