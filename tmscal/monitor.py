"""The live health monitor (``tmscal monitor CONFIG --calib CAL``, docs/lab-day.md,
"Monitor"): during a session it reads the tracker at its frame rate and the robot at every
frame, and checks A X against Z B (and A Y against Z C where the probe is seen) with the
stored calibration; it never moves the robot.

Frames: A = base_from_flange (the robot's report), B / C = tracker_from_marker / probe, X / Y
= flange_from_marker / probe, Z = base_from_tracker; 4×4, mm. Residuals r = [t(E) mm;
rotation vector of E deg], E = (A X)⁻¹ Z N (``calib.diagnose.residuals``).

Time is the tracker's: frame number / frame rate (s since the monitor's first frame), so every
duration below (settling, latency, out of view, the window) counts tracker frames, whatever
the wall clock does (on the mocks' fast clock an hour is 216,000 frames at 60 Hz).

Motion and latency: only still phases are checked. The robot counts as moving at a frame
when its reported pose (or joints) differs from the previous frame's by more than
``robot_tol_mm`` / ``robot_tol_deg``; a frame at tracker time t is checked only when the
robot was still from t − ``settle_s`` (the coil's swing after a move, which the controller
does not report) to t + ``latency_s`` (a bound on the delay between the two devices'
readings: a frame is decided ``latency_s`` after it arrived, once a robot read that late
has been seen). A frame in which a tool jumped from the previous one by more than its
frame noise allows (:data:`JUMP_LEVEL`) is not checked either (the step of a bump, a coil
touched): the window refills after it. The rule itself is :mod:`tmscal.calib.alarm`.

Events (:class:`MonitorEvent`): ``alarm`` (at once: the robot stopped with ``stop_robot``,
the residual's size), then ``diagnosis`` (what moved: ``calib.diagnose`` on the alarm's
window mean, and again on each later still phase while the alarm stands: several poses tell
a tracker move from a coil re-seat, one does not), ``clear``, ``out_of_view`` (a tool
unusable for longer than ``out_of_view_s``) and ``in_view``. Each one goes out as an
OpenIGTLink STATUS message (``stream.StreamServer``).
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import chi2

from .calib import diagnose as dg
from .calib.alarm import LEVEL, Detector, FrameNoise, Rule
from .check import noise_of
from .drivers.base import DeviceError, Robot, Tracker, TrackerFrame
from .errors import CalibrationError
from .formats.calibfile import CalibrationFile
from .geometry import pose_mean, rotation_angle
from .stream import STATUS_CODES, StreamServer

log = logging.getLogger(__name__)

__all__ = ["MonitorSettings", "MonitorEvent", "Monitor", "run_monitor", "JUMP_LEVEL",
           "DEVICE_NAME", "candidates", "EVIDENCE"]

#: a tool whose frame-to-frame residual change has this small a probability under its frame
#: noise (χ²₆ of the whitened difference) jumped: that frame is not checked
JUMP_LEVEL = 1e-6
#: the OpenIGTLink device name of the monitor's STATUS messages
DEVICE_NAME = "TMSCalMonitor"
BODIES = ("marker", "probe")


@dataclass(frozen=True)
class MonitorSettings:
    """The monitor's parameters (seconds of tracker time, mm, degrees): ``window_s`` of
    frames averaged, ``persistence_s`` over the bound before the alarm (None: the window
    and one frame), ``level`` the false-alarm probability of one still phase,
    ``tolerance_mm`` / ``tolerance_deg`` the smallest change that raises an alarm (None:
    any significant one), ``settle_s`` after the robot stops before frames are checked,
    ``latency_s`` the bound on the delay between the robot's and the tracker's readings,
    ``warmup_s`` of still frames from which the tracker's frame noise is estimated,
    ``out_of_view_s`` a tool may be unusable before it is reported, ``robot_tol_mm`` /
    ``robot_tol_deg`` the change of the robot's report between frames that counts as
    motion, ``stop_robot`` the driver's stop at an alarm."""

    window_s: float = 0.25
    persistence_s: float | None = None
    level: float = LEVEL
    tolerance_mm: float | None = None
    tolerance_deg: float | None = None
    settle_s: float = 1.0
    latency_s: float = 0.1
    warmup_s: float = 1.0
    out_of_view_s: float = 2.0
    robot_tol_mm: float = 0.01
    robot_tol_deg: float = 0.01
    stop_robot: bool = False

    def rule(self, rate_hz: float) -> Rule:
        """The decision rule in frames at ``rate_hz`` (``calib.alarm.Rule``)."""
        w = max(1, int(round(self.window_s * rate_hz)))
        k = None if self.persistence_s is None else max(1, int(round(self.persistence_s
                                                                     * rate_hz)))
        return Rule(window=w, persistence=k, level=self.level, tolerance_mm=self.tolerance_mm,
                    tolerance_deg=self.tolerance_deg)


@dataclass
class MonitorEvent:
    """One event: ``kind`` (alarm, diagnosis, clear, out_of_view, in_view), ``t_s``
    (tracker time, s since the monitor's first frame), ``frame`` (the tracker's frame
    number), ``message`` (one line), ``details`` (plain JSON types: residual sizes mm/deg,
    statistic, threshold, the diagnosis, the tool)."""

    kind: str
    t_s: float
    frame: int
    message: str
    details: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"event": self.kind, "t_s": round(self.t_s, 4), "frame": self.frame,
                "message": self.message, **self.details}

    def status(self) -> tuple[int, str]:
        """(OpenIGTLink STATUS code, error name ≤ 20 bytes) of this event."""
        return {"alarm": (STATUS_CODES["error"], "RigChanged"),
                "diagnosis": (STATUS_CODES["error"], "RigChanged"),
                "clear": (STATUS_CODES["ok"], ""),
                "out_of_view": (STATUS_CODES["not_found"], "ToolOutOfView"),
                "in_view": (STATUS_CODES["ok"], "")}.get(self.kind,
                                                        (STATUS_CODES["error"], "Monitor"))


@dataclass
class _Pending:
    t: float
    frame: int
    A: np.ndarray
    N: dict[str, np.ndarray]


class Monitor:
    """The monitor's state, fed one tracker frame and one robot read at a time
    (:meth:`step`); no devices here (``run_monitor`` reads them). ``cf`` the calibration
    file (its noise model: ``check.noise_of``), ``tools`` the tracker's tool names,
    ``rate_hz`` its frame rate."""

    def __init__(self, cf: CalibrationFile, tools: Sequence[str], rate_hz: float,
                 settings: MonitorSettings | None = None) -> None:
        self.cf, self.cal = cf, cf.calibration
        self.settings = s = settings or MonitorSettings()
        self.rate = float(rate_hz)
        if "marker" not in tools:
            raise CalibrationError("tracker.tools has no 'marker': the monitor checks A X "
                                   "against Z B with the coil's marker")
        self.tools = list(tools)
        self.bodies = tuple(b for b in BODIES if b in tools
                            and (b == "marker" or self.cal.Y is not None))
        self.noise = noise_of(cf, self.bodies)
        self.rule = s.rule(self.rate)
        self.detector = Detector(self.rule)
        self.frame_noise = FrameNoise(self.bodies, max(2, int(round(s.warmup_s * self.rate))))
        self.jump = float(chi2.isf(JUMP_LEVEL, 6))
        self.events: list[MonitorEvent] = []
        self.frames = 0
        self.checked = 0
        self.alarms = 0
        self._f0: int | None = None
        self._last_f = 0
        self._t = 0.0
        self._prev_A: np.ndarray | None = None
        self._prev_q: np.ndarray | None = None
        self._last_move = 0.0
        self._hold = 0
        self._pending: deque[_Pending] = deque()
        self._prev: tuple[int, int, dict[str, np.ndarray]] | None = None  # hold, frame, r
        self._S: dict[tuple[int, tuple[str, ...]], np.ndarray] = {}
        self._recent: deque[_Pending] = deque(maxlen=self.rule.window)
        self._episode: list[tuple[np.ndarray, dict[str, np.ndarray]]] = []
        self._episode_hold: int | None = None
        self._to_diagnose: tuple[_Pending, Any, tuple[str, ...]] | None = None
        self._seen: dict[str, float] = {t: 0.0 for t in self.tools}
        self._gone: set[str] = set()
        self.last_step: Any = None
        #: the tracker frame number of the last frame the rule judged (None before)
        self.last_checked: int | None = None

    # --- time --------------------------------------------------------------------------------
    @property
    def t_s(self) -> float:
        """Tracker time now: s since the first frame (frame numbers / frame rate)."""
        return self._t

    @property
    def since_move_s(self) -> float:
        """Tracker seconds since the robot's report last changed (or the first frame)."""
        return self._t - self._last_move

    @property
    def holds(self) -> int:
        """Frames at which the robot was seen moving, and the first: each begins a hold."""
        return self._hold

    def _time(self, frame: int) -> float:
        if self._f0 is None:
            self._f0 = self._last_f = frame
        if frame <= self._last_f and self.frames:  # a counter that wrapped or restarted
            self._t += 1.0 / self.rate
        else:
            self._t += (frame - self._last_f) / self.rate
        self._last_f = frame
        return self._t

    # --- one frame ---------------------------------------------------------------------------
    def step(self, frame: TrackerFrame, A: np.ndarray, joints: np.ndarray | None = None
             ) -> list[MonitorEvent]:
        """One tracker ``frame`` and the robot's report read with it (``A`` 4×4 mm, the
        ``joints`` rad or None); returns the events it raised."""
        t = self._time(int(frame.frame))
        first = self.frames == 0
        self.frames += 1
        out: list[MonitorEvent] = []
        A = np.asarray(A, dtype=float)
        if self.cal.arm is not None:
            if joints is None:
                raise CalibrationError("the calibration carries an identified arm, which "
                                       "recomputes the robot pose from the joints: this "
                                       "robot driver does not report them")
            A = self.cal.robot_poses(A[None], np.asarray(joints, float)[None])[0]
        if first or self._moved(A, joints):
            self._last_move = t
            self._hold += 1
        self._prev_A, self._prev_q = A, None if joints is None else np.asarray(joints, float)
        out += self._views(frame, t)
        N = {b: np.asarray(frame.tools[b].pose, dtype=float) for b in self.bodies
             if b in frame.tools and frame.tools[b].usable}
        self._pending.append(_Pending(t, int(frame.frame), A, N))
        while self._pending and self._pending[0].t <= t - self.settings.latency_s + 1e-9:
            out += self._decide(self._pending.popleft())
        self.events += out
        return out

    def _moved(self, A: np.ndarray, joints: np.ndarray | None) -> bool:
        P = self._prev_A
        if P is None:
            return True
        s = self.settings
        if np.linalg.norm(A[:3, 3] - P[:3, 3]) > s.robot_tol_mm:
            return True
        D = np.linalg.inv(P) @ A
        if float(np.degrees(rotation_angle(D[None])[0])) > s.robot_tol_deg:
            return True
        if joints is not None and self._prev_q is not None:
            return bool(np.max(np.abs(np.degrees(np.asarray(joints, float) - self._prev_q)))
                        > s.robot_tol_deg)
        return False

    def _views(self, frame: TrackerFrame, t: float) -> list[MonitorEvent]:
        out = []
        for tool in self.tools:
            st = frame.tools.get(tool)
            if st is not None and st.usable:
                self._seen[tool] = t
                if tool in self._gone:
                    self._gone.discard(tool)
                    out.append(MonitorEvent("in_view", t, int(frame.frame),
                                            f"{tool} back in view at {t:.2f} s",
                                            {"tool": tool}))
            elif tool not in self._gone and t - self._seen[tool] > self.settings.out_of_view_s:
                self._gone.add(tool)
                why = ("missing" if st is None or st.missing or st.pose is None
                       else "out of the measurement volume")
                out.append(MonitorEvent(
                    "out_of_view", t, int(frame.frame),
                    f"{tool} out of view for {t - self._seen[tool]:.1f} s ({why}; more than "
                    f"{self.settings.out_of_view_s:g} s)", {"tool": tool, "why": why}))
        return out

    def _residual(self, p: _Pending, bodies: tuple[str, ...]) -> tuple[np.ndarray, dg.Frames]:
        fr = dg.frames(self.cal, p.A[None], p.N["marker"][None],
                       p.N["probe"][None] if "probe" in bodies else None)
        return dg.residuals(fr)[0], fr

    def _decide(self, p: _Pending) -> list[MonitorEvent]:
        s = self.settings
        hold = self._hold
        still = p.t - self._last_move >= s.settle_s - 1e-9
        bodies = tuple(b for b in self.bodies if b in p.N)
        if not still or "marker" not in bodies:
            self._unusable()
            return []
        r, fr = self._residual(p, bodies)
        rb = {b: r[6 * i:6 * i + 6] for i, b in enumerate(bodies)}
        jumped = False
        if self._prev is not None and self._prev[0] == hold and self._prev[1] == p.frame - 1:
            for b, v in rb.items():
                if b not in self._prev[2]:
                    continue
                d = v - self._prev[2][b]
                if self.frame_noise.ready:
                    Sf = self.frame_noise.cov((b,))
                    if float(d @ np.linalg.solve(2 * Sf, d)) > self.jump:
                        jumped = True
                else:
                    self.frame_noise.add(b, d)
        self._prev = (hold, p.frame, rb)
        if jumped or not self.frame_noise.ready:
            self._unusable()
            return []
        key = (hold, bodies)
        if key not in self._S:
            self._S = {k: v for k, v in self._S.items() if k[0] == hold}
            self._S[key] = dg.pose_covariance(fr, self.noise)[0]
        self.checked += 1
        self.last_checked = p.frame
        self._recent.append(p)
        st = self.detector.update(r, bodies, self._S[key], self.frame_noise.cov(bodies))
        self.last_step = st
        out: list[MonitorEvent] = []
        if st.over and self.detector.alarmed and self._episode_hold != hold \
                and len(self._recent) == self.rule.window:
            self._episode.append(self._hold_mean())
            self._episode_hold = hold
            if not st.alarm:
                out.append(self._event("diagnosis", p, st, bodies, self._diagnose()))
        if st.alarm:
            self.alarms += 1
            self._episode = [self._hold_mean()]
            self._episode_hold = hold
            self._to_diagnose = (p, st, bodies)
            out.append(self._event("alarm", p, st, bodies, None))
        elif st.clear:
            self._episode, self._episode_hold = [], None
            out.append(MonitorEvent(
                "clear", p.t, p.frame, f"clear at {p.t:.2f} s: A X = Z B within the "
                f"calibration's noise again (T = {st.statistic:.1f} ≤ {st.threshold:.1f})",
                {"statistic": st.statistic, "threshold": st.threshold}))
        return out

    def _unusable(self) -> None:
        self.detector.update(None)
        self._recent.clear()

    def _hold_mean(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The robot pose and the mean tracker poses (4×4 mm) of the window's frames."""
        ps = list(self._recent)
        common = [b for b in self.bodies if all(b in p.N for p in ps)]
        return ps[-1].A, {b: pose_mean(np.stack([p.N[b] for p in ps])) for b in common}

    def _diagnose(self) -> dict[str, Any]:
        eps = self._episode
        bodies = [b for b in self.bodies if all(b in N for _, N in eps)]
        A = np.stack([a for a, _ in eps])
        B = np.stack([N["marker"] for _, N in eps])
        C = np.stack([N["probe"] for _, N in eps]) if "probe" in bodies else None
        try:
            d = dg.diagnose(dg.frames(self.cal, A, B, C), self.noise.for_bodies(bodies)
                            if tuple(bodies) != self.noise.bodies else self.noise)
            out = d.to_json()
        except (CalibrationError, np.linalg.LinAlgError, ValueError) as e:
            return {"changed": None, "error": str(e), "n_poses": len(eps)}
        out["n_poses"] = len(eps)
        return out

    def diagnose_alarm(self) -> MonitorEvent | None:
        """The ``diagnosis`` event of the alarm :meth:`step` just raised (what moved:
        ``calib.diagnose`` on the alarm's window mean, a few tenths of a second of fitting,
        which is why the alarm goes out first), or None when no alarm waits for one."""
        if self._to_diagnose is None:
            return None
        p, st, bodies = self._to_diagnose
        self._to_diagnose = None
        ev = self._event("diagnosis", p, st, bodies, self._diagnose())
        self.events.append(ev)
        return ev

    def _event(self, kind: str, p: _Pending, st: Any, bodies: tuple[str, ...],
               dx: dict[str, Any] | None) -> MonitorEvent:
        m = st.mean
        sizes = {b: {"mm": float(np.linalg.norm(m[6 * i:6 * i + 3])),
                     "deg": float(np.linalg.norm(m[6 * i + 3:6 * i + 6]))}
                 for i, b in enumerate(bodies)}
        res = ", ".join(f"{b} {v['mm']:.3f} mm {v['deg']:.3f}°" for b, v in sizes.items())
        details: dict[str, Any] = {"statistic": st.statistic, "threshold": st.threshold,
                                   "residual": sizes}
        if dx is None:
            msg = (f"ALARM at {p.t:.2f} s (frame {p.frame}): A X ≠ Z B beyond the "
                   f"calibration's noise (T = {st.statistic:.1f} > {st.threshold:.1f} for "
                   f"{self.rule.frames_to_alarm} frames; residual {res})")
        else:
            msg = (f"what moved (at {p.t:.2f} s, {dx.get('n_poses')} still phase(s) since "
                   f"the alarm; residual {res}): {_what_moved(dx)}")
            details.update(diagnosis=dx, changed=dx.get("changed"), candidates=candidates(dx))
        return MonitorEvent(kind, p.t, p.frame, msg, details)

    def covariances(self) -> tuple[tuple[str, ...], np.ndarray, np.ndarray] | None:
        """(bodies, S, Σ_f) of the last hold checked: the residual covariance of that hold
        from the noise model and the learnt frame noise (q×q, mm and deg), or None before
        the first check."""
        if not self._S:
            return None
        (_, bodies), S = list(self._S.items())[-1]
        return bodies, S, self.frame_noise.cov(bodies)

    def summary(self) -> dict[str, Any]:
        """{"frames", "checked" (frames the rule judged), "alarms", "events", "seconds"
        (tracker time), "rule" (window, persistence frames, level, threshold per q)}."""
        return {"frames": self.frames, "checked": self.checked, "alarms": self.alarms,
                "events": len(self.events), "seconds": self._t,
                "rule": {"window": self.rule.window, "persistence": self.rule.frames_to_alarm,
                         "level": self.rule.level,
                         "threshold": {str(6 * n): self.rule.threshold(6 * n)
                                       for n in range(1, len(self.bodies) + 1)}},
                "noise_model": self.noise.source}


#: alternatives within this evidence ratio of the winner (AICc) are named with it
EVIDENCE = 10.0


def candidates(dx: dict[str, Any]) -> list[str]:
    """The changes a diagnosis cannot tell apart: the winner and every alternative within
    an evidence ratio of :data:`EVIDENCE` of it (AICc), the commonest first
    (``calib.diagnose.HYPOTHESES``): at one pose a tracker move and a coil re-seat fit
    equally well."""
    ch = dx.get("changed")
    if ch in (None, "none", "unexplained"):
        return [] if ch is None else [ch]
    alts = {a["changed"]: a for a in dx.get("alternatives") or []}
    best = alts.get(dx.get("winner"), {}).get("aicc")
    if best is None:
        return [ch]
    near = [h for h, a in alts.items() if h != "none"
            and a["aicc"] - best < 2 * np.log(EVIDENCE)]
    order = {h: i for i, h in enumerate(dg.HYPOTHESES)}
    return sorted(set(near) | {ch}, key=lambda h: order.get(h, len(order)))


def _what_moved(dx: dict[str, Any]) -> str:
    """The diagnosis in a few words: the change and its size, or the changes these poses
    cannot tell apart (:func:`candidates`)."""
    ch = dx.get("changed")
    if ch is None:
        return f"not diagnosed ({dx.get('error')})"
    text = str(dx.get("label") or ch)
    if ch in ("none", "unexplained"):
        return text
    size = (f" ({dx['delta_mm']:.3f} mm, {dx['delta_deg']:.3f}°)"
            if dx.get("delta_mm") is not None else "")
    near = candidates(dx)
    if len(near) > 1:
        return (f"{' or '.join(h.replace('_', ' ') for h in near)}{size}: "
                f"{dx.get('n_poses')} still phase(s) cannot tell them apart (another pose "
                "of the robot will)")
    return text + size


def run_monitor(robot: Robot, tracker: Tracker, cf: CalibrationFile,
                settings: MonitorSettings | None = None, *, server: StreamServer | None = None,
                frames: int | None = None, stop: Callable[[], bool] = lambda: False,
                on_event: Callable[[MonitorEvent], None] | None = None,
                on_frame: Callable[[Monitor, TrackerFrame], None] | None = None,
                stall_s: float = 5.0) -> Monitor:
    """Monitor the open ``robot`` and ``tracker`` with the calibration ``cf`` until
    ``stop()`` (checked after every frame) or ``frames`` distinct tracker frames: at every
    frame one robot read (pose, and joints where the driver reports them), then
    :meth:`Monitor.step`. Each event goes to ``on_event`` and, with a ``server``, out as an
    OpenIGTLink STATUS message; at an alarm with ``settings.stop_robot`` the robot's stop
    is called first (its details say ``robot_stopped``). The robot is never moved. A device
    that stops answering (no new tracker frame for ``stall_s`` s, a lost connection) is a
    DeviceError naming it, after a STATUS "DeviceLost" to the clients."""
    s = settings or MonitorSettings()
    mon = Monitor(cf, tracker.tools, tracker.frame_rate_hz, s)
    if server is not None:
        server.send_status(STATUS_CODES["ok"], "", "tmscal monitor: watching",
                           device_name=DEVICE_NAME)
    joints = True
    it = tracker.distinct_frames(frames, stall_s=stall_s)
    try:
        while True:
            try:
                fr = next(it)
            except StopIteration:
                break
            except DeviceError as e:
                raise _lost(server, "tracker", tracker.name, e) from None
            try:
                A = robot.flange_pose()
                q = None
                if joints:
                    try:
                        q = robot.joint_positions()
                    except NotImplementedError:
                        joints = False
            except DeviceError as e:
                raise _lost(server, "robot", robot.name, e) from None
            events = mon.step(fr, A, q)
            while events:
                ev = events.pop(0)
                if ev.kind == "alarm" and s.stop_robot:
                    try:
                        robot.stop()
                        ev.details["robot_stopped"] = True
                        ev.message += "; robot stopped"
                    except DeviceError as e:  # the alarm goes out all the same
                        log.error("the robot's stop failed: %s", e)
                        ev.details["robot_stopped"] = False
                        ev.message += f"; the robot's stop FAILED ({e})"
                if server is not None:
                    code, name = ev.status()
                    server.send_status(code, name, ev.message, device_name=DEVICE_NAME)
                if on_event is not None:
                    on_event(ev)
                if ev.kind == "alarm":  # the alarm out first, then what moved
                    dx = mon.diagnose_alarm()
                    if dx is not None:
                        events.insert(0, dx)
            if on_frame is not None:
                on_frame(mon, fr)
            if stop():
                break
    finally:
        it.close()
    if server is not None:
        server.send_status(STATUS_CODES["exiting"], "", "tmscal monitor: stopped",
                           device_name=DEVICE_NAME)
    return mon


def _lost(server: StreamServer | None, kind: str, name: str, e: DeviceError) -> DeviceError:
    msg = (f"the monitor lost the {kind} ({name}): {e}; nothing is being checked any more")
    if server is not None:
        server.send_status(STATUS_CODES["not_present"], "DeviceLost", msg,
                           device_name=DEVICE_NAME)
    err = type(e)(msg)
    return err if isinstance(err, DeviceError) else DeviceError(msg)
