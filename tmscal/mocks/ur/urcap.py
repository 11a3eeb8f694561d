"""The External Control URCap of the UR mock (Universal Robots'
``Universal_Robots_ExternalControl_URCap``, whose ``RequestProgram`` this follows).

The URCap's program node does not listen: when the operator presses Play, it connects to the
remote PC named in its installation node (host and port, 50002 by default), sends
``request_program\\n`` and runs the URScript the PC answers (ur_rtde's ``FLAG_USE_EXT_UR_CAP``
starts the PC side, ``urcl::control::ScriptSender``, in ``RTDEControlInterface``'s
constructor). When nothing answers, the node shows "Receive program failed" and the program
stops. The mock connects only to a loopback address.
"""

from __future__ import annotations

import logging
import re
import socket
import threading

from ...timing import Deadline
from .controller import RUNTIME_PLAYING, URController

log = logging.getLogger(__name__)

#: What the URCap sends to ask for the program.
PROGRAM_REQUEST = b"request_program\n"
#: The URCap's connect timeout (s) and how long the mock waits for the whole program (s).
CONNECT_TIMEOUT_S = 5.0
RECEIVE_TIMEOUT_S = 5.0
#: How often ``play_when_ready`` tries the PC while waiting for it (s).
RETRY_S = 0.05
#: The last line of ur_rtde's URCap program (header ``# HEADER_BEGIN`` … ``# HEADER_END``, then
#: the control loop up to this line); without it the mock reads until the PC goes quiet.
_LOOP_END = re.compile(r"#\s*NODE_CONTROL_LOOP_ENDS\s*$")
#: Quiet time after which the received bytes are the whole program (s), as the URCap reads
#: while its buffer holds data.
QUIET_S = 0.2


class ExternalControl:
    """The External Control program node of ``controller``: ``play()`` fetches the script
    from ``host:port`` and starts it (``last_script`` is the last one). ``play_when_ready``: a
    background operator presses Play as soon as the PC answers (once per stopped program,
    until ``stop`` is set: the mock's own stop event)."""

    def __init__(self, controller: URController, host: str, port: int, play_when_ready: bool,
                 stop: threading.Event) -> None:
        self.mock = controller
        self.host = host
        self.port = int(port)
        self.play_when_ready = play_when_ready
        self.requests = 0            # programs fetched from the PC
        self.last_script: str | None = None
        self._stop = stop
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self.play_when_ready and self._thread is None:
            self._thread = threading.Thread(target=self._operator, name="ur-urcap",
                                            daemon=True)
            self._thread.start()

    def _operator(self) -> None:
        while not self._stop.wait(RETRY_S):
            if self.mock.runtime_state == RUNTIME_PLAYING:   # nothing to do
                continue
            if self.mock.why_no_program(network=False) is None:
                self.play(quiet=True)

    def fetch(self, quiet: bool = False) -> str | None:
        """The program the PC sends for ``request_program`` (None: no answer)."""
        try:
            with socket.create_connection((self.host, self.port),
                                          timeout=CONNECT_TIMEOUT_S) as s:
                s.sendall(PROGRAM_REQUEST)
                return _receive_program(s)
        except OSError as e:
            if not quiet:
                log.warning("UR mock URCap: the connection to the remote PC at %s:%d could "
                            "not be established (%s): Receive program failed", self.host,
                            self.port, e)
            return None

    def play(self, quiet: bool = False) -> bool:
        """Play pressed: fetch the program and run it. True if it runs."""
        with self.mock._lock:
            why = self.mock.why_no_program(network=False)
        if why is not None:
            log.warning("UR mock URCap: play refused: %s", why)
            return False
        program = self.fetch(quiet)
        if program is None:
            return False
        with self.mock._lock:
            self.requests += 1
            self.last_script = program
            self.mock._start_program("External Control program played")
        return True


def _receive_program(s: socket.socket) -> str | None:
    """The program the PC answers: read until its last line (``_LOOP_END``), the peer closes,
    or, once something arrived, ``QUIET_S`` passes without more (None: nothing arrived)."""
    buf = bytearray()
    deadline = Deadline(RECEIVE_TIMEOUT_S)
    s.settimeout(QUIET_S)
    while not deadline.expired():
        try:
            chunk = s.recv(65536)
        except TimeoutError:
            if buf:
                break
            continue
        if not chunk:
            break
        buf += chunk
        if _LOOP_END.search(buf[-200:].decode("utf-8", "replace")):
            break
    text = buf.decode("utf-8", "replace")
    return text if text.strip() else None
