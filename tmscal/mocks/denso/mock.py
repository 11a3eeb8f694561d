"""The DENSO mock's b-CAP server: one :class:`~tmscal.mocks.server.TCPListener`, and per
connection a loop that frames requests, answers them through the controller's function
table, sends the keep-alives of a running motion and ends it on time."""

from __future__ import annotations

import logging
import math
import socket
import time

from ...drivers.denso.hresult import (
    E_BUSY_PROC,
    E_FAIL,
    E_INVALIDARG,
    E_INVALIDPACKET,
    S_EXECUTING,
    S_OK,
    hresult_name,
)
from ...drivers.denso.packet import Packet, decode_packet, frame_serial, function_name
from ...errors import ProtocolError
from ...sim.rig import SimRig
from ..clock import REAL_TIME, Clock
from ..server import MockDevice, TCPListener
from .args import Refusal
from .controller import DEFAULT_MAX_LINEAR_ACCEL_MM_S2, DEFERRED, DensoController
from .state import DensoFaults, Session

log = logging.getLogger(__name__)

#: Longest wait for a request before the connection loop looks at its motion again (s).
_POLL_S = 0.05


class DensoMock(DensoController, MockDevice):
    """A b-CAP server on ``host:port`` (loopback only; port 0 → ephemeral, a real RC8 uses
    5007) serving ``rig``.

    ``clock``: REAL_TIME (motions take their trapezoidal profile's time) or FAST
    (immediate; ``last_motion_s`` still holds the modelled time).
    ``max_linear_speed_mm_s``: the linear speed at SPEED=100 and ExtSpeed=100 (mm/s).
    ``max_linear_accel_mm_s2``: the linear acceleration (and deceleration) at ACCEL=100 and
    ExtSpeed accel=100 (mm/s²; default the DENSO driver's, so the percentages it sends give
    back the acceleration it was asked for). ``faults``: :class:`DensoFaults`.
    ``motion_time_s``: a fixed duration for every motion (None: the profile's).
    ``robot_names``: names GetRobot accepts.
    ``start()`` returns ``"host:port"``; ``close()`` stops it; usable as a context
    manager. ``stats`` counts requests, moves, keep-alives and busy replies.
    """

    def __init__(self, rig: SimRig, host: str = "127.0.0.1", port: int = 0,
                 clock: Clock = REAL_TIME, max_linear_speed_mm_s: float = 1000.0,
                 faults: DensoFaults | None = None, motion_time_s: float | None = None,
                 robot_names: tuple[str, ...] = ("Arm",),
                 max_linear_accel_mm_s2: float = DEFAULT_MAX_LINEAR_ACCEL_MM_S2) -> None:
        # the listener refuses a non-loopback host before anything else is checked
        self._listener = TCPListener(host, port, self._serve, "DensoMock host")
        super().__init__(rig, clock, max_linear_speed_mm_s, faults, motion_time_s,
                         robot_names, max_linear_accel_mm_s2)

    @property
    def host(self) -> str:
        return self._listener.host

    @property
    def port(self) -> int:
        """The TCP port (the bound one once started)."""
        return self._listener.port

    # --- lifecycle ---------------------------------------------------------------------------
    def _start(self) -> str:
        endpoint = self._listener.start()
        log.info("DENSO b-CAP mock listening on %s", endpoint)
        return endpoint

    def _close(self) -> None:
        self._listener.close()

    # --- serving -----------------------------------------------------------------------------
    def _serve(self, conn: socket.socket) -> None:
        """Serve one connection (the listener's handler) until the peer goes or the mock
        closes."""
        with self._lock:
            self.stats["connections"] += 1
        sess = Session(sock=conn, peer="?")
        try:
            sess.peer = "{}:{}".format(*conn.getpeername()[:2])
            self._loop(sess)
        except OSError as e:
            log.info("DENSO mock: connection %s ended: %s", sess.peer, e)
        finally:
            self._end_session(sess)

    def _loop(self, sess: Session) -> None:
        while not self._listener.stopping:
            self._advance(sess)
            wait = min(_POLL_S, self._keep_stuck_alive(sess))
            if sess.job is not None:
                nxt = sess.job.end
                if sess.job.serial is not None and sess.job.wdt_s:
                    nxt = min(nxt, sess.job.next_keepalive)
                wait = min(wait, max(nxt - self.clock.now(), 0.001))
            if self.coast is not None and not math.isinf(self.coast[1]):
                wait = min(wait, max(self.coast[1] - self.clock.now(), 0.001))
            sess.sock.settimeout(wait)
            try:
                data = sess.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                break
            if not data:
                break
            sess.framer.feed(data)
            if not self._drain(sess):
                break

    def _keep_stuck_alive(self, sess: Session) -> float:
        """Send the keep-alive due for a request left unanswered (the ``stuck_functions``
        fault); seconds until the next one (``_POLL_S`` when none is pending)."""
        if sess.stuck is None:
            return _POLL_S
        serial, due = sess.stuck
        now = time.monotonic()
        if now >= due:
            sess.reply(serial, S_EXECUTING)
            with self._lock:
                self.stats["keepalives"] += 1
            due = now + self.faults.stuck_keepalive_s
            sess.stuck = (serial, due)
        return max(due - now, 0.001)

    def _end_session(self, sess: Session) -> None:
        """The connection is gone: a NEXT motion carries on to its end, the arm and the
        handles are released (the listener closes the socket)."""
        job = sess.job
        if job is not None:
            self.end_motion(job)
            if job.serial is None and not job.halted:
                self.arrive(job.target, job.end)
        sess.job = None
        sess.arm = False
        sess.handles.clear()

    def _advance(self, sess: Session) -> None:
        """Send the keep-alives that are due and finish the motion when its time is up or a
        Robot_Halt (from any connection) stopped it: a halted blocking move fails with
        E_FAIL (a stand-in: the code a real RC8 answers could not be checked)."""
        self.settle(request=False)
        job = sess.job
        if job is None:
            return
        if job.halted:
            sess.job = None
            self.end_motion(job)
            if job.serial is not None:
                sess.reply(job.serial, E_FAIL)
            return
        now = self.clock.now()
        if job.serial is not None and job.wdt_s:
            while job.next_keepalive < job.end and job.next_keepalive <= now:
                sess.reply(job.serial, S_EXECUTING)
                with self._lock:
                    self.stats["keepalives"] += 1
                job.next_keepalive += job.wdt_s
        if now >= job.end:
            sess.job = None
            self.end_motion(job)
            self.arrive(job.target, job.end + job.settle_s)
            if job.serial is not None:
                sess.reply(job.serial, S_OK)

    def _drain(self, sess: Session) -> bool:
        """Answer every complete request in the buffer; False when the connection must end
        (the ``drop_at_request`` / ``drop_rate`` faults)."""
        while True:
            try:
                frame = sess.framer.next_frame()
            except ProtocolError as e:
                log.warning("DENSO mock: bad framing from %s: %s", sess.peer, e)
                continue
            if frame is None:
                return True
            serial = frame_serial(frame)
            k, drop = self._count("requests", self.faults.drop_at_request,
                                  self.faults.drop_rate)
            if drop:
                log.info("DENSO mock: fault: dropping the connection at request %d", k)
                with self._lock:
                    self.stats["dropped"] += 1
                return False
            try:
                pkt = decode_packet(frame)
            except ProtocolError as e:
                log.warning("DENSO mock: malformed request from %s: %s", sess.peer, e)
                sess.reply(serial, E_INVALIDPACKET)
                continue
            self._answer(sess, pkt)

    def _answer(self, sess: Session, pkt: Packet) -> None:
        """Reply to one decoded request: E_BUSY_PROC to any request (Robot_Halt included)
        while this connection runs a move, as DENSO's reference b-CAP server does (Halt must
        come over another connection), else the function's result or the HRESULT it was
        refused with."""
        self._advance(sess)
        self.settle(request=True)
        if sess.job is not None:
            with self._lock:
                self.stats["busy"] += 1
            sess.reply(pkt.serial, E_BUSY_PROC)
            return
        fname = function_name(pkt.code)
        if fname in self.faults.stuck_functions:
            log.info("DENSO mock: fault: %s (serial %d) never answered, only kept alive",
                     fname, pkt.serial)
            sess.stuck = (pkt.serial, time.monotonic())
            return
        try:
            result = self.dispatch(sess, pkt.serial, pkt.code, list(pkt.args))
        except Refusal as r:
            log.info("DENSO mock: %s → 0x%08X (%s): %s", fname, r.code, hresult_name(r.code),
                     r)
            sess.reply(pkt.serial, r.code)
            return
        except (ValueError, ArithmeticError, TypeError) as e:  # a value it cannot use
            log.warning("DENSO mock: %s rejected: %s", fname, e)
            sess.reply(pkt.serial, E_INVALIDARG)
            return
        except OSError:
            raise
        except Exception:  # a mock bug must not end the connection without a reply
            log.exception("DENSO mock: %s failed", fname)
            sess.reply(pkt.serial, E_FAIL)
            return
        if result is not DEFERRED:
            sess.reply(pkt.serial, S_OK, result)


__all__ = ["DensoMock"]
