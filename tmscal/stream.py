"""Live OpenIGTLink streaming of the tracked coil through a calibration (``tmscal stream``).

An OpenIGTLink server (the ``pyigtl`` package) that a navigation program such as 3D Slicer's
OpenIGTLinkIF module connects to as a client. For every distinct tracker frame it sends one
TRANSFORM message per name in :data:`TRANSFORMS` (docs/streaming.md):

==================== ============================================================
device name          transform (4×4, mm; Slicer's "FromToTo" naming: maps From into To)
==================== ============================================================
CoilToRobotBase      robot base ← coil centre (probe): Z · C
CoilToTracker        tracker ← coil centre (probe): C, as the tracker measures it
MarkerToTracker      tracker ← coil marker: B, as the tracker measures it
TrackerToRobotBase   robot base ← tracker: Z of the calibration
==================== ============================================================

Z is the calibration's orthonormal base_from_tracker (the ``Z`` of ``tmscal solve -o``). With a
tracker distortion in the calibration (the ``ml`` solver), CoilToRobotBase is Z applied to the
undistorted probe pose, as the robot would place the coil (``Calibration.placement``); the
tracker poses are sent as measured. A body that is missing or (partly) out of the tracker's
volume in a frame is not sent for that frame, as PlusServer does by default: the client keeps
the last pose it received (docs/streaming.md says how to notice).

OpenIGTLink carries float32: about 1e-4 mm at 1,500 mm from the tracker.

This module has no CLI: :mod:`tmscal.cli.stream` parses the options and shows the status.
"""

from __future__ import annotations

import logging
import socket
import socketserver
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyigtl
from pyigtl.comm import OpenIGTLinkBase

from .calib import Calibration
from .drivers.base import Tracker, TrackerFrame

log = logging.getLogger(__name__)

__all__ = ["TRANSFORMS", "MAX_NAME_BYTES", "DEFAULT_PORT", "frame_transforms", "StreamServer",
           "StreamStats", "stream_frames"]

#: OpenIGTLink's registered TCP port, the default of Slicer's OpenIGTLinkIF and PlusServer
DEFAULT_PORT = 18944

#: the OpenIGTLink header's device name field is 20 bytes
MAX_NAME_BYTES = 20

#: device name → what it is (frames and formula); the order in which each frame is sent
TRANSFORMS: dict[str, str] = {
    "CoilToRobotBase": "robot base ← coil centre (probe): Z · C",
    "CoilToTracker": "tracker ← coil centre (probe): C as the tracker measures it",
    "MarkerToTracker": "tracker ← coil marker: B as the tracker measures it",
    "TrackerToRobotBase": "robot base ← tracker: Z of the calibration",
}


def frame_transforms(frame: TrackerFrame, cal: Calibration, marker: str = "marker",
                     probe: str = "probe") -> dict[str, np.ndarray]:
    """The transforms of :data:`TRANSFORMS` for one tracker frame (4×4 float64, mm), by
    device name. TrackerToRobotBase is always there; MarkerToTracker only when the ``marker``
    tool is usable in the frame (present, inside the volume), CoilToTracker and
    CoilToRobotBase only when the ``probe`` tool is."""
    Z = np.asarray(cal.Z, dtype=float)
    out: dict[str, np.ndarray] = {}
    C = _usable(frame, probe)
    if C is not None:
        targets, _, _ = cal.placement(C[None])  # undistorted when the calibration says so
        out["CoilToRobotBase"] = Z @ targets[0]
        out["CoilToTracker"] = C
    B = _usable(frame, marker)
    if B is not None:
        out["MarkerToTracker"] = B
    out["TrackerToRobotBase"] = Z
    return out


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


class _Handler(socketserver.BaseRequestHandler):
    """One connected client: send what is queued, read (and drop) what the client sends. A
    client that hangs up or sends garbage ends this connection only, with one log line; the
    server then waits for the next client."""

    def handle(self) -> None:
        srv: StreamServer = self.server  # type: ignore[assignment]
        peer = f"{self.client_address[0]}:{self.client_address[1]}"
        with srv.lock_outgoing_messages:
            srv.outgoing_messages.clear()  # nothing stale from before this client
        srv.peer = peer
        srv._connected = True
        self.request.settimeout(0.01)
        log.info("OpenIGTLink client %s connected", peer)
        try:
            while not srv.communication_thread_stop_requested:
                while srv._receive_message_from_socket(self.request):
                    pass
                while srv._send_queued_message_from_socket(self.request):
                    pass
        except Exception as e:  # a peer on the network: any failure ends its connection
            log.info("OpenIGTLink client %s disconnected (%s)", peer, e)
        finally:
            srv._connected = False
            srv.peer = None
            srv.clients += 1


class StreamServer(pyigtl.OpenIGTLinkServer):  # type: ignore[misc]
    """``pyigtl.OpenIGTLinkServer`` bound to ``host`` (pyigtl's own chooses 127.0.0.1 or the
    address of a network interface), without the SIGINT/SIGTERM handlers pyigtl installs (the
    caller owns Ctrl-C), and quiet when a client hangs up. One client at a time (a second one
    waits until the first disconnects). ``port`` 0 picks a free port; ``port`` and ``host``
    are then what was bound. Whether ``host`` may be off loopback is the caller's decision
    (:func:`tmscal.net.is_loopback`). Use as a context manager, or ``start()`` and ``stop()``."""

    allow_reuse_address = True

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT) -> None:
        OpenIGTLinkBase.__init__(self)
        self.address_family = _family(host)
        socketserver.TCPServer.__init__(self, (host, port), _Handler)
        self.host, self.port = self.server_address[0], int(self.server_address[1])
        self._previous_signal_handlers: dict[int, Any] = {}
        self.peer: str | None = None
        self.clients = 0  # connections that have ended
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Accept clients in a background thread."""
        self._thread = threading.Thread(target=self.serve_forever, name="igtl-server",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Disconnect the client and close the listening socket (safe twice)."""
        if self._thread is None:
            self.server_close()
            return
        self.communication_thread_stop_requested = True
        self.shutdown()
        self.server_close()
        self._thread.join(5.0)
        self._thread = None

    def __enter__(self) -> StreamServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def send_transforms(self, transforms: Mapping[str, np.ndarray], timestamp: float) -> int:
        """Queue one TRANSFORM message per item (device name → 4×4 mm) for the connected
        client; nothing is queued without a client. Returns the number queued."""
        if not self.is_connected():
            return 0
        n = 0
        for name, M in transforms.items():
            if len(name.encode("utf-8")) > MAX_NAME_BYTES:
                raise ValueError(f"device name {name!r} is longer than {MAX_NAME_BYTES} bytes")
            msg = pyigtl.TransformMessage(np.asarray(M, dtype=float), timestamp=timestamp,
                                          device_name=name)
            n += bool(self.send_message(msg, wait=False))
        return n


@dataclass
class StreamStats:
    """What a stream has done so far: distinct tracker ``frames`` read, frames ``sent`` to a
    client, TRANSFORM ``messages`` queued, per tool the frames it was not usable in
    (``unseen``), the measured ``rate_hz`` (tracker frames per second over the last second),
    and the connected client (``peer``, "host:port", or None)."""

    frames: int = 0
    sent: int = 0
    messages: int = 0
    unseen: Counter[str] = field(default_factory=Counter)
    rate_hz: float | None = None
    peer: str | None = None
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
    ``frames`` distinct frames were read. ``rate_hz`` sends at most that many frames a second
    (the others are read and dropped); None sends every frame (the tracker's frame rate).
    Each message carries the frame's arrival time (seconds since 1970). ``on_frame`` gets the
    running :class:`StreamStats` after every frame. A tracker without a new frame for
    ``stall_s`` seconds raises DeviceTimeout (the tracker's own errors pass through)."""
    stats = StreamStats()
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
            stats.peer = server.peer
            if fr.host_time - last_sent >= period:
                stamp = time.time() - (time.monotonic() - fr.host_time)
                n = server.send_transforms(frame_transforms(fr, cal), stamp)
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
