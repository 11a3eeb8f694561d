"""A protocol-level ATI Net F/T: RDT over UDP on a loopback address (``tmscal.drivers.ati``
speaks to it unchanged).

Each start request (``START_REALTIME`` with a sample count; 0 streams until ``STOP``) starts
a stream to the requesting address, ``rdt_sequence`` 1, 2, … as the real sensor numbers it.
``START_BUFFERED`` and ``START_MULTI_UNIT`` are answered the same way, one record per
datagram (the real sensor's several records per datagram are not modelled). ``ft_sequence``
counts the mock's samples over its life. On the real-time clock records go out at
``rate_hz``; on the fast clock a stream of k records is sent at once (a stream without a
count sends ``FAST_STREAM_CAP`` records, then waits for STOP).
``SET_SOFTWARE_BIAS`` subtracts the current reading from later ones; ``STOP`` ends the stream.
Requests that do not parse are logged and ignored, as the sensor ignores them.

Each record is ``source()`` — the noise-free wrench [F N, τ N·m] in the sensor frame, e.g. the
sim rig's gravity wrench (``tmscal.mocks.wrench``) — plus Gaussian noise (``noise_n`` N per
force channel, ``noise_nm`` N·m per torque channel), in counts with the configured counts per
unit. Faults (``ATIFaults``): drop every k-th record, swap records pairwise every k-th, a
status word from the k-th record on, or no answer at all.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ...drivers.ati import codec
from ...net import listen_error, loopback_family, url_host
from ..clock import REAL_TIME, Clock
from ..server import MockDevice

log = logging.getLogger(__name__)

__all__ = ["ATIFaults", "ATINetFTMock", "FAST_STREAM_CAP"]

#: records a fast-clock stream without a count sends before it waits for STOP
FAST_STREAM_CAP = 1000
_POLL_S = 0.05
#: a UDP client's address, as ``recvfrom`` gives it (host, port)
Peer = tuple[str, int]
#: a fast-clock stream goes out in chunks of this many records with a short pause between,
#: so that a client's UDP receive buffer does not overflow (which would read as lost records)
_FAST_CHUNK, _FAST_PAUSE_S = 32, 0.0005


def _every(name: str, v: int | None) -> int | None:
    if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 2):
        raise ValueError(f"ATIFaults.{name}: expected an integer ≥ 2 or null, got {v!r}")
    return v


@dataclass(frozen=True)
class ATIFaults:
    """Faults to inject; records are counted from 1 over the mock's life, None disables.

    ``drop_every``: every k-th record is not sent (lost). ``reorder_every``: every k-th record
    is held back and sent after the next one. ``bad_status_from``: from the k-th record on,
    the status word is ``bad_status`` (default 0x80000001: the error summary bit and bit 0).
    ``mute``: requests are read and never answered (a sensor that does not stream)."""

    drop_every: int | None = None
    reorder_every: int | None = None
    bad_status_from: int | None = None
    bad_status: int = 0x80000001
    mute: bool = False

    def __post_init__(self) -> None:
        _every("drop_every", self.drop_every)
        _every("reorder_every", self.reorder_every)
        if self.bad_status_from is not None and (isinstance(self.bad_status_from, bool)
                                                 or not isinstance(self.bad_status_from, int)
                                                 or self.bad_status_from < 1):
            raise ValueError(f"ATIFaults.bad_status_from: expected an integer ≥ 1 or null, "
                             f"got {self.bad_status_from!r}")
        if not isinstance(self.bad_status, int) or not 0 < self.bad_status < 2**32:
            raise ValueError(f"ATIFaults.bad_status: expected a status word in 1…2³²−1, got "
                             f"{self.bad_status!r}")


class ATINetFTMock(MockDevice):
    """The Net F/T mock on UDP ``host:port`` (loopback only: ``NotLoopbackError`` otherwise;
    port 0: an ephemeral one; 49152 is the sensor's). ``source``: a callable returning the
    noise-free wrench (6,) [F N, τ N·m], sensor frame (default: zero). ``counts_per_force``
    / ``counts_per_torque``: the calibration the mock encodes with. ``seed``: the noise's
    RNG seed."""

    def __init__(self, source: Callable[[], np.ndarray] | None = None,
                 host: str = "127.0.0.1", port: int = 0, clock: Clock = REAL_TIME,
                 faults: ATIFaults = ATIFaults(), noise_n: float = 0.0,
                 noise_nm: float = 0.0, counts_per_force: float = 1_000_000.0,
                 counts_per_torque: float = 1_000_000.0, rate_hz: float = 1000.0,
                 seed: int = 0) -> None:
        self.family = loopback_family(host, "ATI Net F/T mock")
        for name, v in (("noise_n", noise_n), ("noise_nm", noise_nm)):
            if not (isinstance(v, int | float) and np.isfinite(v) and v >= 0):
                raise ValueError(f"ATINetFTMock: {name} must be a finite number ≥ 0, got {v!r}")
        if not (isinstance(rate_hz, int | float) and 0 < rate_hz <= 10_000):
            raise ValueError(f"ATINetFTMock: rate_hz must be in (0, 10000], got {rate_hz!r}")
        codec.counts_from_wrench(np.zeros(6), counts_per_force, counts_per_torque)  # checks
        self.source = source or (lambda: np.zeros(6))
        self.host, self.port = host, int(port)
        self.clock, self.faults = clock, faults
        self.noise = np.array([noise_n] * 3 + [noise_nm] * 3, dtype=np.float64)
        self.cpf, self.cpt = float(counts_per_force), float(counts_per_torque)
        self.rate_hz = float(rate_hz)
        self.rng = np.random.default_rng(seed)
        #: records sent (and dropped by the fault) over the mock's life; requests seen
        self.sent = 0
        self.requests: list[tuple[int, int]] = []
        self.bias_counts = np.zeros(6, dtype=np.int64)
        self._sock: socket.socket | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._record_no = 0
        self._held: bytes | None = None
        #: the current stream: (peer, records left or None for unbounded, next rdt_sequence)
        self._stream: tuple[Peer, int | None, int] | None = None

    @property
    def endpoint(self) -> str:
        """``host:port`` the driver sends to."""
        return f"{url_host(self.host)}:{self.port}"

    def _start(self) -> str:
        s = socket.socket(self.family, socket.SOCK_DGRAM)
        try:
            s.bind((self.host, self.port))
        except OSError as e:
            s.close()
            raise listen_error(e, "ATI Net F/T mock", self.host, self.port, "UDP") from e
        s.settimeout(_POLL_S)
        self._sock, self.port = s, s.getsockname()[1]
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name=f"ati-mock:{self.port}",
                                        daemon=True)
        self._thread.start()
        return self.endpoint

    def _close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def getsockname(self) -> object:
        """The bound address (as ``socket.getsockname()``); ``OSError`` before ``start()``."""
        if self._sock is None:
            raise OSError("ATI Net F/T mock: not bound")
        return self._sock.getsockname()

    # --- serving ------------------------------------------------------------------------------

    def _loop(self) -> None:
        assert self._sock is not None
        next_t = time.monotonic()
        while not self._stop.is_set():
            wait = _POLL_S if self._stream is None or self.clock.fast else \
                max(0.0, next_t - time.monotonic())
            self._sock.settimeout(wait if wait > 0 else 1e-6)
            try:
                data, peer = self._sock.recvfrom(64)
                self._on_request(data, peer)
                next_t = time.monotonic()
            except TimeoutError:
                pass
            except OSError as e:   # the socket closed under us
                log.debug("ATI mock: %s", e)
                return
            if self._stream is None:
                continue
            if self.clock.fast:
                self._burst()
            elif time.monotonic() >= next_t:
                self._emit()
                next_t += 1.0 / self.rate_hz

    def _on_request(self, data: bytes, peer: Peer) -> None:
        try:
            command, count = codec.parse_request(data)
        except Exception as e:  # the sensor ignores what it cannot parse
            log.warning("ATI mock: %s; ignored", e)
            return
        self.requests.append((command, count))
        if self.faults.mute:
            return
        if command in (codec.START_REALTIME, codec.START_BUFFERED, codec.START_MULTI_UNIT):
            self._stream = (peer, count or None, 1)
            self._held = None
        elif command == codec.STOP:
            self._stream = None
        elif command == codec.SET_SOFTWARE_BIAS:
            self.bias_counts = self.bias_counts + self._counts()

    def _burst(self) -> None:
        """Fast clock: the whole stream (at most ``FAST_STREAM_CAP`` records) at once."""
        assert self._stream is not None
        left = self._stream[1]
        for i in range(FAST_STREAM_CAP if left is None else left):
            if self._stream is None:
                return
            self._emit()
            if i % _FAST_CHUNK == _FAST_CHUNK - 1:
                time.sleep(_FAST_PAUSE_S)   # let the client's receive buffer drain
        if self._stream is not None and self._stream[1] is None:
            self._stream = (self._stream[0], 0, self._stream[2])   # wait for STOP

    def _counts(self) -> np.ndarray:
        w = np.asarray(self.source(), dtype=np.float64).reshape(6)
        w = w + self.rng.normal(0.0, 1.0, 6) * self.noise
        return codec.counts_from_wrench(w, self.cpf, self.cpt)

    def _emit(self) -> None:
        """One record of the current stream, through the faults."""
        assert self._stream is not None and self._sock is not None
        peer, left, seq = self._stream
        if left == 0:
            return
        self._record_no += 1
        k, f = self._record_no, self.faults
        status = f.bad_status if f.bad_status_from is not None and k >= f.bad_status_from \
            else 0
        counts = np.clip(self._counts() - self.bias_counts, -(2**31), 2**31 - 1)
        rec = codec.Record(seq % 2**32, k % 2**32, status,
                           tuple(int(c) for c in counts))  # type: ignore[arg-type]
        self._stream = (peer, None if left is None else left - 1, seq + 1)
        data = codec.pack_record(rec)
        self.sent += 1
        if f.drop_every is not None and k % f.drop_every == 0:
            return
        if f.reorder_every is not None and k % f.reorder_every == 0 and \
                self._stream[1] != 0:
            self._held = data
            return
        self._send(data, peer)
        if self._held is not None:
            self._send(self._held, peer)
            self._held = None

    def _send(self, data: bytes, peer: Peer) -> None:
        assert self._sock is not None
        try:
            self._sock.sendto(data, peer)
        except OSError as e:
            log.debug("ATI mock: send to %s failed: %s", peer, e)
