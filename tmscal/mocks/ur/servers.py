"""The UR mock's three servers on one loopback address, each a ``TCPListener``: RTDE (30004),
dashboard (29999) and primary script (30003), around the simulated controller
(``controller.URController``). ``URMock`` is the whole device (a ``MockDevice``)."""

from __future__ import annotations

import logging
import math
import re
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ...net import loopback_family
from ...sim.rig import SimRig
from ..clock import REAL_TIME, Clock
from ..server import MockDevice, TCPListener
from .controller import (
    ROBOT_MODE_RUNNING,
    SCRIPT_PERIOD_S,
    URController,
    URFaults,
)
from .dashboard import DASHBOARD_BANNER, Dashboard
from .rtde import (
    CONTROLLER_VERSION,
    HEADER,
    OUTPUT_FREQUENCY,
    PROTOCOL_VERSION,
    PROTOCOL_VERSIONS,
    PackageType,
    Recipe,
    encode_package,
    parse_names,
    recv_exact,
)
from .urcap import ExternalControl

log = logging.getLogger(__name__)

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003

#: Output recipe frequencies (Hz) the mock accepts (e-Series controllers stream at ≤ 500 Hz).
MIN_FREQUENCY_HZ, MAX_FREQUENCY_HZ = 1.0, 500.0
#: Output frequency before a client sets one (Hz).
DEFAULT_FREQUENCY_HZ = 125.0
#: How often a connection handler looks whether the mock is closing (s).
POLL_S = 0.2
#: Longest dashboard line and script the mock buffers before it drops the connection (bytes).
MAX_DASHBOARD_LINE = 65536
MAX_SCRIPT_BYTES = 4_000_000



#: the controller software a mock answers for a CB3 arm, and for an e-Series one (or none)
CB3_VERSION = (3, 15, 8, 106339)
E_SERIES_VERSION = (5, 11, 0, 108249)


def _identity(rig: SimRig, version: tuple[int, int, int, int] | None, serial: str | None,
              model: str | None) -> tuple[tuple[int, ...], str, str]:
    """(version, serial, model) a controller of the rig's arm answers (the arm registry's
    entry for a UR arm; a UR5e's without one), the given ones kept. ValueError for an arm
    whose joints RTDE cannot report (not six)."""
    from ...calib.kinematics import ARMS

    arm = rig.arm_nominal
    if arm is not None and arm.n_joints != 6:
        raise ValueError(f"the UR mock reports six joints (RTDE actual_q); mock.kinematics.arm "
                         f"{arm.name} has {arm.n_joints}")
    spec = ARMS.get(arm.name) if arm is not None else None
    if spec is None or spec.vendor != "Universal Robots":
        spec = ARMS["ur5e"]
        default_serial = "20185500001"
    else:
        default_serial = spec.mock_serial or ""
    cb3 = spec.generation == "CB3"
    return (tuple(version) if version is not None else CB3_VERSION if cb3 else E_SERIES_VERSION,
            default_serial if serial is None else serial,
            spec.controller_model if model is None else model)


class URMock(URController, MockDevice):
    """A Universal Robots controller (RTDE 30004, dashboard 29999, script 30003) serving ``rig``.

    Parameters
    ----------
    rig:
        The simulated rig; moves call ``rig.move_flange`` (base_from_flange 4×4 mm) and the
        reported TCP pose is ``rig.reported_flange()`` · ``tcp_offset``.
    host:
        Loopback address to bind (127.0.0.0/8, ::1 or localhost; anything else raises
        ``ConfigError``); ports are UR's fixed ones.
    clock:
        ``REAL_TIME``: moves take their trapezoidal profile's time; ``FAST``: at once.
        Data streaming runs at the client's requested rate on both.
    faults:
        ``URFaults`` to inject.
    version:
        Controller software version (major, minor, bugfix, build) reported on RTDE and by the
        dashboard's ``PolyscopeVersion``. ≥ 5.6 makes ur_rtde query version and serial.
        None: as the rig's arm's controller would (``mock.kinematics``: a CB3 arm 3.15.8,
        an e-Series one 5.11.0; no UR arm: 5.11.0).
    serial:
        Serial number reported by ``get serial number`` (None: the arm registry's for the
        rig's UR arm, ``ArmSpec.mock_serial``; otherwise a UR5e's, 20185500001).
    model:
        Robot model reported by ``get robot model`` (None: the rig's UR arm's, as its
        controller answers it: ``UR5`` for a UR5 and a UR5e alike; otherwise ``UR5``).
        A rig whose arm is not a six-joint arm is refused (RTDE reports six joints).
    program_running:
        True (default): a control program is already running at start (runtime_state 2,
        ready), as it must be for clients using ``flags=0``; with the default upload flag
        ur_rtde then stops it and uploads its own. False: the controller starts stopped and
        only a script upload (or dashboard ``play`` after one) makes it run.
    robot_mode, remote_control:
        The operator's state (see ``URController``): e.g. ``ROBOT_MODE_POWER_OFF`` for a
        powered-off robot, ``remote_control=False`` for a pendant in Local Control. Tests
        change them while the mock runs (``power_off``, ``power_on``, ``release_brakes``,
        ``set_remote_control``; the dashboard's ``power on``/``power off``/``brake release``).
    urcap_port, urcap_host:
        The External Control URCap (Universal Robots' ``Universal_Robots_ExternalControl_
        URCap``): when ``urcap_port`` is set, the loaded program is an External Control
        program, and ``pendant_play()`` (the operator pressing Play) connects to the remote
        PC at ``urcap_host:urcap_port``, sends ``request_program``, and runs the script that
        ur_rtde's script sender (``FLAG_USE_EXT_UR_CAP``) answers. Nothing is fetched over the
        script port. ``play_when_ready=True`` presses Play as soon as the PC answers.
    tcp_offset:
        The active TCP, flange_from_tcp 4×4 mm (default None: zero, TCP = flange), as
        ``getTCPOffset`` answers it: RTDE reports the TCP pose and ``moveL`` moves the TCP on
        the straight line (the flange then turns about it).
    """

    def __init__(self, rig: SimRig, host: str = "127.0.0.2", clock: Clock = REAL_TIME,
                 faults: URFaults = URFaults(),
                 version: tuple[int, int, int, int] | None = None,
                 serial: str | None = None, model: str | None = None,
                 program_running: bool = True, robot_mode: int = ROBOT_MODE_RUNNING,
                 remote_control: bool = True, urcap_port: int | None = None,
                 urcap_host: str = "127.0.0.1", play_when_ready: bool = False,
                 tcp_offset: np.ndarray | None = None) -> None:
        loopback_family(host, "URMock host")  # refuses a non-loopback host at once
        loopback_family(urcap_host, "URMock urcap_host")
        full_version, serial, model = _identity(rig, version, serial, model)
        if len(full_version) != 4:
            raise ValueError(f"version must be (major, minor, bugfix, build), got "
                             f"{full_version!r}")
        super().__init__(rig, clock=clock, faults=faults,
                         program_running=program_running and urcap_port is None,
                         robot_mode=robot_mode, remote_control=remote_control,
                         tcp_offset=tcp_offset)
        self._stop = threading.Event()
        #: wakes the idle script loop: a client connected, a move began, the mock stops
        self._wake = threading.Event()
        self._clients = 0
        self.urcap = ExternalControl(self, urcap_host, urcap_port, play_when_ready,
                                     self._stop) if urcap_port is not None else None
        self.host = host
        self.version = tuple(int(v) for v in full_version)
        self.serial = serial
        self.model = model
        self.last_script: str | None = None
        self.scripts_received = 0
        self.dashboard_log: list[str] = []
        self._listeners: list[TCPListener] = []
        self._script_thread: threading.Thread | None = None
        self._dashboard = Dashboard(self, self.version, serial, model,
                                    None if self.urcap is None else self.urcap.play)

    @property
    def last_urcap_script(self) -> str | None:
        """The last program the External Control URCap fetched from the PC (None: none, or
        no URCap)."""
        return None if self.urcap is None else self.urcap.last_script

    # --- lifecycle ----------------------------------------------------------------------------

    def _start(self) -> str:
        """Bind the three ports on ``host`` and serve in daemon threads. Returns the host
        string to give to ur_rtde (``RTDEControlInterface(host)``)."""
        if self._listeners:
            return self.host
        try:
            for port, handler, what in ((RTDE_PORT, self._serve_rtde, "UR RTDE"),
                                        (DASHBOARD_PORT, self._serve_dashboard, "UR dashboard"),
                                        (SCRIPT_PORT, self._serve_script, "UR script")):
                listener = TCPListener(self.host, port, self._served(handler), what)
                self._listeners.append(listener)
                listener.start()
        except OSError:
            self._close()
            raise
        self._script_thread = threading.Thread(target=self._script_loop, name="ur-script",
                                               daemon=True)
        self._script_thread.start()
        if self.urcap is not None:
            self.urcap.start()
        log.info("UR mock serving on %s (RTDE %d, dashboard %d, script %d)", self.host,
                 RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT)
        return self.host

    def _close(self) -> None:
        """Stop every thread and close every socket (safe to call twice)."""
        self._stop.set()
        self._wake.set()
        for listener in self._listeners:
            listener.close()
        t = self._script_thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout=2.0)
        self._script_thread = None
        self._listeners.clear()

    def _alive(self) -> bool:
        return not self._stop.is_set()

    def _link_down(self) -> None:
        """The network link fails: listeners close (reconnects are refused) and every client
        connection is shut down. Called with ``_lock`` held: nothing is joined here."""
        for listener in self._listeners:
            listener.close(join_s=0.0)

    def _motion_started(self) -> None:
        self._wake.set()

    def _busy(self) -> bool:
        """True while the script loop must tick: a client is connected (it commands and
        reads the registers) or a move runs (it ends on a tick, a client or not)."""
        return self._clients > 0 or self._motion is not None

    def _served(self, handler: Callable[[socket.socket], None]
                ) -> Callable[[socket.socket], None]:
        """``handler`` counted as a connected client for as long as it runs."""
        def serve(conn: socket.socket) -> None:
            with self._lock:
                self._clients += 1
            self._wake.set()
            try:
                handler(conn)
            finally:
                with self._lock:
                    self._clients -= 1
        return serve

    def _script_loop(self) -> None:
        """The control script's main loop: one ``_tick`` every ``SCRIPT_PERIOD_S`` while a
        client is connected or a move runs; otherwise it sleeps until one connects or a move
        begins (``_wake``), so that an idle mock takes no CPU (250 wake-ups a second did)."""
        nxt = time.monotonic()
        while self._alive():
            if not self._busy():
                self._wake.clear()
                if not self._busy() and self._alive():  # nothing was missed since the check
                    self._wake.wait()
                nxt = time.monotonic()
                continue
            self._tick()
            nxt += SCRIPT_PERIOD_S
            delay = nxt - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                nxt = time.monotonic()

    # --- the three servers --------------------------------------------------------------------

    def _serve_rtde(self, conn: socket.socket) -> None:
        conn.settimeout(POLL_S)
        _RTDEConnection(self, conn).run()

    def _serve_dashboard(self, conn: socket.socket) -> None:
        conn.settimeout(POLL_S)
        conn.sendall(DASHBOARD_BANNER)
        buf = b""
        while self._alive():
            try:
                chunk = conn.recv(4096)
            except TimeoutError:
                continue
            if not chunk:
                return
            buf += chunk
            while b"\n" in buf:
                raw, buf = buf.split(b"\n", 1)
                line = raw.decode("utf-8", "replace").strip()
                if not line:
                    continue
                self.dashboard_log.append(line)
                reply, hang_up = self._dashboard.reply(line)
                log.debug("UR mock dashboard: %r -> %r", line, reply)
                data = reply.encode()
                bad = self.faults.non_utf8_dashboard_reply
                if bad is not None and line.lower() == bad.strip().lower():
                    log.info("UR mock dashboard: fault: %r answered with bytes that are not "
                             "UTF-8", line)
                    data = b"\xff\xfe" + data + b"\x80"
                conn.sendall(data + b"\n")
                if hang_up:
                    return
            if len(buf) > MAX_DASHBOARD_LINE:
                log.warning("UR mock dashboard: line too long, dropping the connection")
                return

    def _serve_script(self, conn: socket.socket) -> None:
        conn.settimeout(POLL_S)
        buf = bytearray()
        while self._alive():
            try:
                chunk = conn.recv(65536)
            except TimeoutError:
                chunk = None
            if chunk == b"":
                self._take_script(bytes(buf))
                return
            if chunk:
                buf += chunk
                if len(buf) > MAX_SCRIPT_BYTES:
                    log.warning("UR mock script port: script too large, dropped")
                    return
            if self._take_script(bytes(buf)):
                buf.clear()

    def _take_script(self, data: bytes) -> bool:
        """Run a complete program (``def name(): … end`` at column 0, or ``sec``). True if
        ``data`` held one."""
        text = data.decode("utf-8", "replace")
        m = re.match(r"\s*(def|sec)\s+(\w+)\s*\(", text)
        if not m or not re.search(r"(^|\n)end$", text.rstrip()):
            return False
        self.last_script = text
        self.scripts_received += 1
        log.info("UR mock: received program %r (%d bytes)", m.group(2), len(data))
        with self._lock:
            why = self.why_no_program(network=True)
            if why is None:
                self._start_program(f"script {m.group(2)!r} uploaded")
            else:   # the real controller shows a popup and runs nothing
                log.warning("UR mock: program %r not started: %s", m.group(2), why)
        return True

    def pendant_play(self) -> bool:
        """The operator presses Play on the pendant: with the External Control URCap, the
        program node fetches the script from the PC and runs it; otherwise the loaded program
        (re)starts. True if a program now runs."""
        if self.urcap is not None:
            return self.urcap.play()
        with self._lock:
            if not self._program_loaded or self.why_no_program(network=False) is not None:
                return False
            self._start_program("pendant play")
            return True


class _RTDEConnection:
    """One RTDE client: setup requests answered in order (a handler per package type), then
    a thread that streams the output recipe."""

    def __init__(self, mock: URMock, conn: socket.socket) -> None:
        self.mock = mock
        self.conn = conn
        self.send_lock = threading.Lock()
        self.output: Recipe | None = None
        self.output_getters: list[Callable[[float], Any]] = []
        self.frequency = DEFAULT_FREQUENCY_HZ
        self.output_refused = False   # an output recipe was refused (bad frequency)
        self.inputs: dict[int, Recipe] = {}
        self.streaming = threading.Event()
        self.closed = threading.Event()
        self.stream_thread: threading.Thread | None = None
        self.handlers: dict[int, Callable[[bytes], None]] = {
            PackageType.RTDE_REQUEST_PROTOCOL_VERSION: self._on_protocol_version,
            PackageType.RTDE_GET_URCONTROL_VERSION: self._on_controller_version,
            PackageType.RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS: self._on_setup_outputs,
            PackageType.RTDE_CONTROL_PACKAGE_SETUP_INPUTS: self._on_setup_inputs,
            PackageType.RTDE_CONTROL_PACKAGE_START: self._on_start,
            PackageType.RTDE_CONTROL_PACKAGE_PAUSE: self._on_pause,
            PackageType.RTDE_DATA_PACKAGE: self._on_data,
        }

    def alive(self) -> bool:
        return self.mock._alive() and not self.closed.is_set()

    def send(self, ptype: PackageType, payload: bytes = b"") -> None:
        with self.send_lock:
            self.conn.sendall(encode_package(ptype, payload))

    def run(self) -> None:
        try:
            while self.alive():
                head = recv_exact(self.conn, HEADER.size, self.alive)
                if head is None:
                    return
                size, ptype = HEADER.unpack(head)
                if size < HEADER.size:
                    log.warning("UR mock RTDE: bad package size %d; closing", size)
                    return
                payload = recv_exact(self.conn, size - HEADER.size, self.alive)
                if payload is None:
                    return
                self.handle(ptype, payload)
        finally:
            self.closed.set()
            self.streaming.clear()

    def handle(self, ptype: int, payload: bytes) -> None:
        handler = self.handlers.get(ptype)
        if handler is None:
            log.debug("UR mock RTDE: ignoring package type %r (%d bytes)", chr(ptype),
                      len(payload))
            return
        handler(payload)

    def _on_protocol_version(self, payload: bytes) -> None:
        version = (PROTOCOL_VERSION.unpack(payload[:PROTOCOL_VERSION.size])[0]
                   if len(payload) >= PROTOCOL_VERSION.size else 0)
        self.send(PackageType.RTDE_REQUEST_PROTOCOL_VERSION,
                  bytes([1 if version in PROTOCOL_VERSIONS else 0]))

    def _on_controller_version(self, payload: bytes) -> None:
        self.send(PackageType.RTDE_GET_URCONTROL_VERSION,
                  CONTROLLER_VERSION.pack(*self.mock.version))

    def _on_setup_outputs(self, payload: bytes) -> None:
        reply = PackageType.RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS
        if len(payload) < OUTPUT_FREQUENCY.size:
            self.send(reply, b"\x00")
            return
        freq = OUTPUT_FREQUENCY.unpack(payload[:OUTPUT_FREQUENCY.size])[0]
        if not (math.isfinite(freq) and MIN_FREQUENCY_HZ <= freq <= MAX_FREQUENCY_HZ):
            log.warning("UR mock RTDE: output frequency %r Hz outside [%g, %g]: recipe "
                        "refused", freq, MIN_FREQUENCY_HZ, MAX_FREQUENCY_HZ)
            self.output_refused = True
            self.send(reply, b"\x00")
            return
        self.frequency = freq
        self.output = Recipe.from_names(parse_names(payload[OUTPUT_FREQUENCY.size:]))
        self.output_getters = [self.mock.value_getter(n) for n in self.output.names]
        log.debug("UR mock RTDE: output recipe at %.0f Hz: %s", self.frequency,
                  ",".join(self.output.names))
        self.send(reply, self.output.setup_reply(1))

    def _on_setup_inputs(self, payload: bytes) -> None:
        recipe = Recipe.from_names(parse_names(payload))
        rid = len(self.inputs) + 1
        self.inputs[rid] = recipe
        log.debug("UR mock RTDE: input recipe %d: %s", rid, ",".join(recipe.names))
        self.send(PackageType.RTDE_CONTROL_PACKAGE_SETUP_INPUTS, recipe.setup_reply(rid))

    def _on_start(self, payload: bytes) -> None:
        reply = PackageType.RTDE_CONTROL_PACKAGE_START
        if self.output_refused and self.output is None:
            self.send(reply, b"\x00")  # the output recipe was refused: nothing to stream
            return
        self.send(reply, b"\x01")
        self.streaming.set()
        if self.stream_thread is None and self.output is not None:
            self.stream_thread = threading.Thread(target=self.stream, daemon=True,
                                                  name="ur-rtde-stream")
            self.stream_thread.start()

    def _on_pause(self, payload: bytes) -> None:
        self.streaming.clear()
        self.send(PackageType.RTDE_CONTROL_PACKAGE_PAUSE, b"\x01")

    def _on_data(self, payload: bytes) -> None:
        """An input data package: registers (and external_force_torque) written, then one
        control-script cycle."""
        if not payload:
            return
        rid = payload[0]
        recipe = self.inputs.get(rid)
        if recipe is None:
            log.warning("UR mock RTDE: data for unknown input recipe %d ignored", rid)
            return
        if len(payload) != recipe.packer.size:
            log.warning("UR mock RTDE: input recipe %d: %d bytes, expected %d; ignored", rid,
                        len(payload) - 1, recipe.packer.size - 1)
            return
        mock = self.mock
        with mock._lock:
            for name, values in recipe.unpack(payload):
                mock.write_input(name, values)
            log.debug("UR mock RTDE: input recipe %d, cmd %d (runtime_state %d, "
                      "output_int_register_0 %d)", rid, mock.in_int[0], mock.runtime_state,
                      mock.out_int[0])
        mock._tick()

    def stream(self) -> None:
        """Send the output recipe at the requested frequency (wall-clock on every clock)."""
        assert self.output is not None
        period = 1.0 / min(max(self.frequency, MIN_FREQUENCY_HZ), MAX_FREQUENCY_HZ)
        nxt = time.monotonic()
        mock = self.mock
        try:
            while self.alive():
                if self.streaming.is_set():
                    with mock._lock:
                        now = mock.clock.now()
                        data = self.output.pack(1, [get(now) for get in self.output_getters])
                    self.send(PackageType.RTDE_DATA_PACKAGE, data)
                nxt += period
                delay = nxt - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                elif delay < -0.1:
                    nxt = time.monotonic()
        except OSError as e:
            log.debug("UR mock RTDE stream ended: %s", e)
        finally:
            self.closed.set()
