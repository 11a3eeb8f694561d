"""The ATI Net F/T driver: RDT records over UDP (``codec``), counts → N and N·m with the
sensor calibration's counts per unit, lost and reordered records counted from
``rdt_sequence``.

``read(n)`` asks for a stream of ``n`` records (``START_REALTIME`` with count n) and returns
them in order, (n, 6) [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame. UDP may lose or
reorder datagrams: a gap in ``rdt_sequence`` counts as lost records, a record older than one
already taken counts as reordered and is dropped (it would be out of time order). When records
are missing, the remainder is asked for again, until ``n`` are in hand. More lost plus
reordered records than ``max_lost_share`` of ``n`` in one read is a ``DeviceError`` naming the
counts: the network, not the sensor, needs fixing. A record whose status word is not 0 is a
``DeviceError`` naming the status bits (``codec.describe_status``); no record within
``timeout_s`` is a ``DeviceTimeout``; a refused port (ICMP unreachable) is ``ConnectionLost``.
``close()`` sends ``STOP``.
"""

from __future__ import annotations

import logging
import socket
from typing import Any

import numpy as np

from ...errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError
from ...net import connect_problem
from ...timing import Deadline
from ..base import ForceTorque
from . import codec
from .settings import ATISettings

log = logging.getLogger(__name__)

__all__ = ["ATINetFT"]

#: the options' defaults, declared once in ATISettings.OPTIONS
_OPT = ATISettings.defaults()


def _positive(name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) or v <= 0:
        raise ValueError(f"ATINetFT: {name} must be a finite number > 0, got {v!r}")
    return float(v)


class ATINetFT(ForceTorque):
    """An ATI Net F/T sensor at ``host`` (UDP ``port``, 49152 on the device).

    ``counts_per_force`` (counts per N) and ``counts_per_torque`` (counts per N·m) are the
    sensor calibration's ``cfgcpf``/``cfgcpt`` (its web page or ``netftapi2.xml``); there is
    no default, because a wrong one scales every reading. ``timeout_s``: longest wait for one
    record. ``max_lost_share``: lost + reordered records tolerated per ``read(n)``, as a
    share of n (at least 1 record)."""

    name = "ati"

    def __init__(self, host: str, counts_per_force: float, counts_per_torque: float,
                 port: int = codec.PORT, timeout_s: float = _OPT["timeout_s"],
                 max_lost_share: float = _OPT["max_lost_share"]) -> None:
        super().__init__()
        if not isinstance(host, str) or not host:
            raise ValueError("ATINetFT: host must be a non-empty address")
        if isinstance(port, bool) or not isinstance(port, int) or not 0 < port < 65536:
            raise ValueError(f"ATINetFT: port must be a UDP port, got {port!r}")
        self.host, self.port = host, port
        self.counts_per_force = _positive("counts_per_force", counts_per_force)
        self.counts_per_torque = _positive("counts_per_torque", counts_per_torque)
        o = ATISettings.check_options("ATINetFT", timeout_s=timeout_s,
                                      max_lost_share=max_lost_share)
        self.timeout_s: float = o["timeout_s"]
        self.max_lost_share: float = o["max_lost_share"]
        #: records lost and reordered over the driver's life (``read`` adds to them)
        self.lost = 0
        self.reordered = 0
        self._sock: socket.socket | None = None
        self._where = f"ati {host}:{port}"

    # --- lifecycle ----------------------------------------------------------------------------

    def _open(self) -> None:
        try:
            infos = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_DGRAM)
            family, _, _, _, addr = infos[0]
            s = socket.socket(family, socket.SOCK_DGRAM)
            s.connect(addr)  # only the sensor's datagrams are received
        except OSError as e:
            why = connect_problem(e, self.host, self.port, "ft.host, ft.port", proto="UDP")
            raise ConnectionLost(f"{self._where}: cannot open UDP socket ({why or e})",
                                 device=self.name) from e
        s.settimeout(self.timeout_s)
        try:   # room for a burst of records while Python is busy elsewhere
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        except OSError:  # pragma: no cover - a platform that refuses: the default stays
            pass
        self._sock = s
        self._send(codec.STOP)  # a stream left running by an earlier client
        self._drain()

    def _close(self) -> None:
        if self._sock is None:
            return
        try:
            self._send(codec.STOP)
        except DeviceError as e:
            log.debug("%s: stop on close failed: %s", self._where, e)
        self._sock.close()
        self._sock = None

    def identity(self) -> dict[str, Any]:
        """Driver, address and the counts per unit in use."""
        return {"driver": self.name, "host": self.host, "port": self.port,
                "counts_per_force": self.counts_per_force,
                "counts_per_torque": self.counts_per_torque}

    # --- commands -----------------------------------------------------------------------------

    def bias(self) -> None:
        """Software bias: the sensor subtracts its current reading from every later record
        (``SET_SOFTWARE_BIAS``). Self-calibration identifies the bias instead; do not bias
        between the readings of one calibration."""
        if not self.is_open:
            raise DeviceError(f"{self._where}: bias() on a sensor that is not open",
                              device=self.name)
        self._send(codec.SET_SOFTWARE_BIAS)

    def _send(self, command: int, count: int = 0) -> None:
        assert self._sock is not None
        try:
            self._sock.send(codec.pack_request(command, count))
        except OSError as e:
            raise ConnectionLost(f"{self._where}: {codec.COMMANDS[command]} not sent ({e})",
                                 device=self.name) from e

    def _drain(self) -> None:
        """Discard whatever datagrams are queued (the tail of an earlier stream)."""
        assert self._sock is not None
        self._sock.setblocking(False)
        try:
            while True:
                self._sock.recv(64)
        except (BlockingIOError, OSError):
            pass
        finally:
            self._sock.settimeout(self.timeout_s)

    # --- reading ------------------------------------------------------------------------------

    def _read(self, n: int) -> np.ndarray:
        allowed = max(1, int(self.max_lost_share * n))
        counts: list[tuple[int, ...]] = []
        bad = [0, 0]   # lost, reordered in this read
        while len(counts) < n:
            self._drain()
            self._stream(n - len(counts), counts, bad, allowed)
        self.lost += bad[0]
        self.reordered += bad[1]
        return codec.wrench_from_counts(np.array(counts[:n], dtype=np.float64),
                                        self.counts_per_force, self.counts_per_torque)

    def _stream(self, k: int, out: list[tuple[int, ...]], bad: list[int], allowed: int) -> None:
        """One stream of ``k`` records appended to ``out`` in order; lost and reordered ones
        added to ``bad``. The stream ends at its last record, or when it goes quiet after at
        least one record (its tail was lost)."""
        self._send(codec.START_REALTIME, k)
        last = 0
        while last < k:
            rec = self._recv(got=len(out), total=len(out) + k - last, quiet_ok=last > 0)
            if rec is None:   # the tail of the stream was lost
                bad[0] += k - last
                self._check_losses(bad, allowed, len(out))
                return
            if rec.status != 0:
                self._send(codec.STOP)
                raise DeviceError(f"{self._where}: sensor reports "
                                  f"{codec.describe_status(rec.status)} (record "
                                  f"{rec.rdt_sequence})", code=rec.status, device=self.name)
            step = codec.sequence_step(last, rec.rdt_sequence)
            if step <= 0 or rec.rdt_sequence > k:
                bad[1] += 1
                if step <= 0 and bad[0] > 0:
                    bad[0] -= 1          # a record counted lost arrived late after all
            else:
                bad[0] += step - 1
                last = rec.rdt_sequence
                out.append(rec.counts)
            self._check_losses(bad, allowed, len(out))

    def _check_losses(self, bad: list[int], allowed: int, got: int) -> None:
        if bad[0] + bad[1] > allowed:
            self._send(codec.STOP)
            raise DeviceError(f"{self._where}: {bad[0]} records lost and {bad[1]} reordered "
                              f"after {got} good ones (at most {allowed} tolerated: "
                              "max_lost_share); check the network between sensor and "
                              "computer", device=self.name)

    def _recv(self, got: int, total: int, quiet_ok: bool) -> codec.Record | None:
        """The next record; None when ``quiet_ok`` and nothing came for ``timeout_s``."""
        assert self._sock is not None
        deadline = Deadline(self.timeout_s)
        while True:
            try:
                data = self._sock.recv(64)
            except TimeoutError:
                if quiet_ok:
                    return None
                raise DeviceTimeout(f"{self._where}: no RDT record within {self.timeout_s:g} "
                                    f"s ({got} of {total} received)", device=self.name) \
                    from None
            except OSError as e:   # ICMP port unreachable on a connected UDP socket
                why = connect_problem(e, self.host, self.port, "ft.host, ft.port",
                                      proto="UDP", service="the Net F/T's RDT stream")
                raise ConnectionLost(f"{self._where}: {why or e}", device=self.name) from e
            try:
                return codec.parse_record(data)
            except ProtocolError as e:
                if deadline.expired():
                    raise ProtocolError(f"{self._where}: {e}", device=self.name) from e
                log.warning("%s: %s; datagram skipped", self._where, e)
