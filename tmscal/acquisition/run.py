"""The acquisition run: move → settle → sample → append, for every pose of the plan.

* The plan is regenerated from (kind, P0, seed, ranges) stored in the session header, so
  ``resume`` continues the same plan and skips the indices already recorded — also after a
  crash (each pose is one fsynced line; a torn last line is cut off).
* Every pose is checked against the safety envelope before the first move.
* A device fault (timeout, corrupt reply, lost connection) is retried a bounded number of
  times with a reconnect; a robot fault (protective or emergency stop) stops at once. Either
  way the run ends with ``AcquisitionStopped`` naming the cause, the session intact and
  resumable.
* ``should_stop()`` is polled between poses (the CLI sets it on Ctrl-C): the pose in flight
  is finished, the robot stopped, and the session left valid.
* Skipped poses are watched over the last ``run.skip_window`` poses (``skips.SkipWatch``): too
  many warn once, far too many stop the run (``AcquisitionStopped``) naming the reason.
* ``on_phase(i, phase)`` reports what pose i is doing: "moving", "settling", "sampling" (and
  "reconnecting" after a device fault), for a progress display.

Poses: base_from_flange (A), tracker_from_marker (B), tracker_from_probe (C); 4×4 mm.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import RigConfig
from ..drivers.base import (
    ConfigError,
    DeviceError,
    Envelope,
    Robot,
    RobotFault,
    SafetyError,
    Tracker,
)
from ..errors import SessionError, TmscalError
from ..session import PoseRecord, SessionWriter, make_header, validate_record
from .devices import envelope_for, make_robot, make_tracker
from .plan import PlanSpec, check_plan
from .sample import PoseSample, sample_pose
from .settings import SamplingSettings as _Settings
from .settings import sampling_settings as _settings
from .skips import SkipWatch

log = logging.getLogger(__name__)

__all__ = ["AcquisitionStopped", "AcquireResult", "acquire", "resume_command"]


class AcquisitionStopped(TmscalError):
    """The run stopped before the plan was complete; the session is valid and resumable."""


@dataclass
class AcquireResult:
    """What a run did: the session path, poses recorded / skipped / planned, whether it
    stopped early (Ctrl-C), device faults recovered, wall time (s), poses new in this run,
    and ``notes`` (settings a resumed run took from the session header)."""

    path: Path
    recorded: int
    skipped: int
    total: int
    stopped: bool
    faults: int
    elapsed_s: float
    new_poses: int
    notes: list[str] = field(default_factory=list)


class _Devices:
    """The open robot and tracker, with reconnect."""

    def __init__(self, cfg: RigConfig, tracker_port: str | None, robot_host: str | None,
                 robot_port: int | None) -> None:
        self.cfg = cfg
        self.tracker_port = tracker_port
        self.robot_host = robot_host
        self.robot_port = robot_port
        self.robot: Robot | None = None
        self.tracker: Tracker | None = None

    def open(self, envelope: Any = None) -> None:
        self.robot = make_robot(self.cfg, envelope, self.robot_host, self.robot_port)
        self.robot.open()
        self.tracker = make_tracker(self.cfg, self.tracker_port)
        self.tracker.open()

    def close(self, stop_robot: bool = False) -> None:
        if self.robot is not None:
            if stop_robot:
                try:
                    self.robot.stop()
                except Exception:  # best effort on the way out
                    log.warning("stopping the robot failed", exc_info=True)
            try:
                self.robot.close()
            except Exception:
                log.warning("closing the robot failed", exc_info=True)
        if self.tracker is not None:
            try:
                self.tracker.close()
            except Exception:
                log.warning("closing the tracker failed", exc_info=True)


_LETTER = {"marker": "B", "probe": "C"}


def _record(i: int, P: np.ndarray, s: PoseSample, t: float) -> PoseRecord:
    """A session line: samples keyed A/B/C as the format says, spreads per body name."""
    samples = {_LETTER.get(k, k): v for k, v in s.samples.items()}
    return PoseRecord(index=i, A=s.A, B=s.bodies.get("marker"), C=s.bodies.get("probe"),
                      commanded=P, time=t, samples=samples, spread=s.spread,
                      skipped=s.problem, joints_rad=s.joints)


_POSE_TOL_MM = 1e-6
#: on --resume the flange must be this close (mm) to P0 or to the path from the last recorded
#: pose to the next one: where an interrupted run left it
RESUME_TOLERANCE_MM = 50.0


def _distance_to_segment(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance (mm) from point x to the segment a–b (3-vectors, mm)."""
    ab = b - a
    den = float(ab @ ab)
    u = 0.0 if den == 0 else float(np.clip((x - a) @ ab / den, 0.0, 1.0))
    return float(np.linalg.norm(x - (a + u * ab)))


def _check_robot_where_run_stopped(here: np.ndarray, plan: np.ndarray, p0: np.ndarray,
                                   done: set[int], path: Any) -> None:
    """On resume, the flange (base_from_flange, mm) must be near P0, or near the straight
    path from the last recorded pose to the next planned one, as an interrupted run leaves
    it; otherwise the header's P0 is not this rig's (or the arm was moved): SessionError."""
    x = here[:3, 3]
    last = max((i for i in done if i < len(plan)), default=-1)
    a = p0[:3, 3] if last < 0 else plan[last][:3, 3]
    b = plan[min(last + 1, len(plan) - 1)][:3, 3]
    d = min(float(np.linalg.norm(x - p0[:3, 3])), _distance_to_segment(x, a, b))
    if not d <= RESUME_TOLERANCE_MM:
        raise SessionError(
            f"{path}: the flange is at {np.round(x, 1).tolist()} mm, {d:.1f} mm from both the "
            f"session's P0 {np.round(p0[:3, 3], 1).tolist()} mm and where the run stopped "
            f"(tolerance {RESUME_TOLERANCE_MM:g} mm): the session belongs to another set-up, "
            "or the arm was moved; move it back near P0 to resume. Nothing was moved.")


def _check_resume(cfg: RigConfig, session: Any, spec: PlanSpec, plan: np.ndarray) -> None:
    """Refuse to resume a session into a different rig or plan: the header's devices and
    plan must match the config, and the header's plan must reproduce every commanded pose
    already recorded (an edited or foreign header would not). Raises SessionError."""
    where = f"{session.path}"
    hint = "resume with the config the session was recorded with, or start a new session"
    devs = session.header.get("devices")
    devs = devs if isinstance(devs, dict) else {}
    for role, sec in (("robot", cfg.robot), ("tracker", cfg.tracker)):
        rec = devs.get(role)
        rec_driver = rec.get("driver") if isinstance(rec, dict) else None
        if sec is not None and rec_driver != sec.driver:
            raise SessionError(f"{where}: the session was recorded with {role} driver "
                               f"{rec_driver!r}; {cfg.path} configures {sec.driver!r}; {hint}")
    bodies = session.bodies
    if cfg.tracker is not None and bodies != list(cfg.tracker.tools):
        raise SessionError(f"{where}: the session's bodies {bodies} differ from the config's "
                           f"tracker.tools {list(cfg.tracker.tools)}; {hint}")
    want = {"kind": cfg.plan.kind, "seed": cfg.plan.seed, "radius_mm": cfg.plan.radius_mm,
            "rotation_deg": cfg.plan.rotation_deg}
    for k, v in want.items():
        got = getattr(spec, k)
        if got != v:
            raise SessionError(f"{where}: the session's plan.{k} is {got!r}; {cfg.path} says "
                               f"{v!r}; {hint}")
    if not isinstance(cfg.plan.start, str):
        d = float(np.abs(spec.p0
                         - np.asarray(cfg.plan.start, dtype=float)).max())
        if d > _POSE_TOL_MM:
            raise SessionError(f"{where}: the session's P0 differs from the config's "
                               f"plan.start (by up to {d:.3g} mm); {hint}")
    for rec in session.poses:
        if rec.commanded is None or rec.index >= len(plan):
            continue
        d = float(np.abs(rec.commanded - plan[rec.index]).max())
        if not d <= _POSE_TOL_MM:
            raise SessionError(
                f"{where}: pose {rec.index} was commanded to "
                f"{np.round(rec.commanded[:3, 3], 1).tolist()} mm but the header's plan "
                f"puts it at {np.round(plan[rec.index][:3, 3], 1).tolist()} mm: the header "
                "was edited or belongs to another run; refusing to resume")


def open_new_run(cfg: RigConfig, out: Path, dev: _Devices, n: int | None
                 ) -> tuple[PlanSpec, np.ndarray, Envelope]:
    """Start a new run into ``out`` (SessionError if it exists): open the devices with the
    config's caps and box, take P0 from the robot (or ``plan.start``), build the plan of ``n``
    poses (None: the config's) and check all of it against the envelope around P0 before
    anything moves; the robot then carries that envelope. Poses base_from_flange, mm."""
    if out.exists():
        raise SessionError(f"{out}: already exists; use --resume to continue it, or "
                           "choose another file")
    dev.open(envelope_for(cfg, None))  # speed caps and the box, until P0 is known
    assert dev.robot is not None
    p0 = (dev.robot.flange_pose() if isinstance(cfg.plan.start, str)
          else np.asarray(cfg.plan.start, dtype=float))
    spec = PlanSpec.from_config(cfg.plan, p0, n)
    plan = spec.poses()
    envelope = envelope_for(cfg, p0)
    check_plan(plan, envelope)
    dev.robot.envelope = envelope
    return spec, plan, envelope


def _start_or_resume(cfg: RigConfig, out: Path, dev: _Devices, resume: bool,
                     poses: int | None, samples: int | None
                     ) -> tuple[SessionWriter | None, PlanSpec, np.ndarray, Envelope,
                                _Settings]:
    """Open the devices and work out the plan. A new run takes P0 from the robot (or the
    config) and writes nothing yet; a resumed run locks the session, regenerates its plan
    from the header and checks it against the config. Either way every plan pose is checked
    against the config's envelope before anything moves."""
    writer: SessionWriter | None = None
    if resume:
        writer = SessionWriter.resume(out)
        header = writer.session.header
        # a run extended by --poses earlier keeps its length unless told otherwise
        last = max((r.index for r in writer.session.poses), default=-1)
        p_hdr = header.get("plan")
        n0 = p_hdr.get("poses", 0) if isinstance(p_hdr, dict) else 0
        spec = PlanSpec.from_header(header)
        n = poses or (last + 1 if last + 1 > n0 else None)
        if n is not None:
            spec = spec.with_n(n)
        plan = spec.poses()
        _check_resume(cfg, writer.session, spec, plan)
        envelope = envelope_for(cfg, spec.p0)
        check_plan(plan, envelope)
        dev.open(envelope)
        settings = _settings(cfg, header, samples)
        summary = writer.session.damage_summary()
        if summary:
            settings.notes.append(f"{out}: {summary} (their poses are acquired again)")
    else:
        spec, plan, envelope = open_new_run(cfg, out, dev, poses)
        settings = _settings(cfg, None, samples)
    assert dev.robot is not None
    here = dev.robot.flange_pose()
    if writer is not None:
        _check_robot_where_run_stopped(here, plan, spec.p0,
                                       writer.session.indices(), out)
    v = envelope.violations(here)
    if v:
        raise SafetyError(f"the robot is at {np.round(here[:3, 3], 1).tolist()} mm, "
                          f"outside the safety envelope around P0 ({'; '.join(v)}); "
                          "move it near P0 first. Nothing was moved.")
    return writer, spec, plan, envelope, settings


def acquire(cfg: RigConfig, output: str | Path, *, resume: bool = False,
            poses: int | None = None, samples: int | None = None,
            tracker_port: str | None = None, robot_host: str | None = None,
            robot_port: int | None = None,
            on_pose: Callable[[int, int, PoseRecord], None] | None = None,
            on_start: Callable[[int, int, int], None] | None = None,
            on_phase: Callable[[int, str], None] | None = None,
            should_stop: Callable[[], bool] = lambda: False,
            sleep: Callable[[float], None] = time.sleep) -> AcquireResult:
    """Run (or resume) an acquisition into session file ``output``.

    ``poses``/``samples`` override the config (on a resume, the session header's settings
    are used unless overridden; ``AcquireResult.notes`` says so). ``on_start(done, total,
    skipped)`` is called once the plan is known (poses already in the session, of them
    skipped); ``on_phase(i, phase)`` as pose i moves, settles and samples; ``on_pose(done,
    total, record)`` after each pose is saved.
    ``run.retries`` bounds the reconnects for one fault: the count starts again after a pose
    succeeds. Raises SafetyError (nothing moved), ConfigError, SessionError, or
    AcquisitionStopped (session intact, resumable; the message says how)."""
    out = Path(output)
    if cfg.tracker is None or "marker" not in cfg.tracker.tools:
        raise ConfigError(f"{cfg.path}: key 'tracker.tools': name the marker tool 'marker' "
                          "(and the probe 'probe')")
    t_start = time.monotonic()
    dev = _Devices(cfg, tracker_port, robot_host, robot_port)
    writer: SessionWriter | None = None
    faults = new = 0
    stopped = clean = False
    hint = "resume with: " + resume_command(cfg.path, out, tracker_port, robot_host)
    try:
        writer, spec, plan, envelope, st = _start_or_resume(cfg, out, dev, resume, poses,
                                                             samples)
        for note in st.notes:
            log.warning("resuming %s with %s", out, note)
        if writer is None:
            writer = _create_session(out, cfg, dev, spec, st)
        done = writer.session.indices()
        t_offset = max((p.time for p in writer.session.poses), default=0.0)
        total = len(plan)
        if on_start:
            on_start(len(done & set(range(total))), total,
                     sum(p.skipped is not None for p in writer.session.poses if p.index < total))
        watch = SkipWatch(cfg.run)
        for i in range(total):
            if i in done:
                continue
            if should_stop():
                stopped = True
                break
            rec, n_faults = _pose_with_reconnect(
                dev, cfg, envelope, i, plan[i], st, sleep,
                lambda: t_offset + time.monotonic() - t_start,
                lambda: (f"The session {out} holds {len(writer.session.poses)} poses; "
                         f"{hint}"), on_phase)
            faults += n_faults
            _save_pose(writer, rec, watch, total, on_pose, hint)
            new += 1
        clean = True
        recs = [p for p in writer.session.poses if p.index < total]
        return AcquireResult(path=out, recorded=sum(p.skipped is None for p in recs),
                             skipped=len(recs) - sum(p.skipped is None for p in recs),
                             total=total, stopped=stopped, faults=faults,
                             elapsed_s=time.monotonic() - t_start, new_poses=new,
                             notes=st.notes)
    finally:
        dev.close(stop_robot=not clean)
        if writer is not None:
            writer.close()


def _save_pose(writer: SessionWriter, rec: PoseRecord, watch: SkipWatch, total: int,
               on_pose: Callable[[int, int, PoseRecord], None] | None, hint: str) -> None:
    """Append pose ``rec`` (recorded as skipped if the reader would reject it), report it,
    and apply the skip thresholds: a warning is logged; past ``run.stop_skip_share`` the run
    stops with AcquisitionStopped naming the reason and how to resume."""
    rec = _valid_or_skipped(rec)
    writer.append(rec)
    if on_pose:
        on_pose(len(writer.session.indices() & set(range(total))), total, rec)
    warning, stop_reason = watch.add(rec)
    if warning:
        log.warning("pose %d: %s", rec.index, warning)
    if stop_reason:
        raise AcquisitionStopped(f"pose {rec.index}: {stop_reason}. The session "
                                 f"{writer.path} holds {len(writer.session.poses)} poses; "
                                 f"{hint}")


def _create_session(out: Path, cfg: RigConfig, dev: _Devices, spec: PlanSpec,
                    st: _Settings) -> SessionWriter:
    """A new session file (locked) whose header records the config, the devices' identity,
    the plan and the sampling settings."""
    assert dev.robot is not None and dev.tracker is not None
    header = make_header(
        dev.tracker.tools, config=cfg.raw,
        devices={"robot": dev.robot.identity(), "tracker": dev.tracker.identity()},
        plan=spec.to_header(), sampling=st.to_header())
    return SessionWriter.create(out, header)


def _valid_or_skipped(rec: PoseRecord) -> PoseRecord:
    """The record if the session reader will accept it, else the same pose recorded as
    skipped with the reason (e.g. a non-finite or non-rigid pose from a device), so that one
    bad measurement neither ends the run nor reaches the file."""
    try:
        return validate_record(rec)
    except SessionError as e:
        log.warning("pose %d: invalid measurement, recorded as skipped: %s", rec.index, e)
        return PoseRecord(index=rec.index, A=None, B=None, C=None, commanded=rec.commanded,
                          time=rec.time, samples={}, spread={},
                          skipped=f"invalid measurement ({e})")


def resume_command(config: str | Path | None, out: str | Path,
                   tracker_port: str | None = None, robot_host: str | None = None) -> str:
    """The command that resumes a run: device overrides are repeated; the plan and the
    sampling settings need not be, as a resumed run takes them from the session header."""
    cmd = f"tmscal acquire {config} -o {out} --resume"
    if tracker_port:
        cmd += f" --tracker-port {tracker_port}"
    if robot_host:
        cmd += f" --robot-host {robot_host}"
    return cmd


def with_reconnect(dev: _Devices, cfg: RigConfig, envelope: Envelope, what: str, i: int,
                   step: Callable[[], PoseRecord], sleep: Callable[[float], None],
                   state: Callable[[], str],
                   on_phase: Callable[[int, str], None] | None = None
                   ) -> tuple[PoseRecord, int]:
    """Run ``step`` (one pose or configuration, ``what`` i), reconnecting after device
    faults: at most ``run.retries`` reconnects for it (the count is per fault, not per run).
    Returns the record and the number of faults recovered. A robot fault, a failed reconnect
    or too many faults raise AcquisitionStopped whose message ends with ``state()`` (what the
    session holds, how to resume)."""
    faults = 0
    while True:
        try:
            return step(), faults
        except RobotFault as e:
            raise AcquisitionStopped(f"{what} {i}: robot fault: {e}. {state()} (clear the "
                                     "fault at the robot first)") from e
        except DeviceError as e:
            faults += 1
            if faults > cfg.run.retries:
                raise AcquisitionStopped(f"{what} {i}: {e} (after {cfg.run.retries} "
                                         f"reconnects). {state()}") from e
            log.warning("%s %d: %s; reconnecting (%d of %d)", what, i, e, faults,
                        cfg.run.retries)
            if on_phase:
                on_phase(i, "reconnecting")
            dev.close(stop_robot=True)
            sleep(cfg.run.reconnect_wait_s)
            try:
                dev.open(envelope)
            except DeviceError as e2:
                raise AcquisitionStopped(f"{what} {i}: reconnect failed ({e2}) after: {e}. "
                                         f"{state()}") from e2


def _pose_with_reconnect(dev: _Devices, cfg: RigConfig, envelope: Envelope, i: int,
                         P: np.ndarray, st: _Settings, sleep: Callable[[float], None],
                         now: Callable[[], float], state: Callable[[], str],
                         on_phase: Callable[[int, str], None] | None = None
                         ) -> tuple[PoseRecord, int]:
    """One plan pose i through :func:`with_reconnect` (``now()``: the session time, s)."""
    return with_reconnect(dev, cfg, envelope, "pose", i,
                          lambda: _one_pose(dev, i, P, st, sleep, now(), on_phase),
                          sleep, state, on_phase)


def _one_pose(dev: _Devices, i: int, P: np.ndarray, st: _Settings,
              sleep: Callable[[float], None], t: float,
              on_phase: Callable[[int, str], None] | None = None) -> PoseRecord:
    """Move to plan pose i, settle and sample; a pose whose bodies were not seen well enough
    is sampled once more (moving again), then recorded as skipped with the reason.
    ``on_phase(i, phase)`` hears "moving", "settling" and "sampling"."""
    assert dev.robot is not None and dev.tracker is not None
    s: PoseSample | None = None
    phase = (lambda name: on_phase(i, name)) if on_phase else None
    for attempt in range(2):
        if phase:
            phase("moving")
        dev.robot.move_to(P)
        s = sample_pose(dev.robot, dev.tracker, st.samples, st.settle_s, st.min_share,
                        st.max_frames_factor, sleep=sleep, robot_reads=st.robot_reads,
                        on_phase=phase, settle=st.settle, still_window_s=st.still_window_s,
                        still_tol_mm=st.still_tol_mm, sem_mm=st.sem_mm,
                        min_samples=st.min_samples)
        if s.problem is None:
            break
        log.info("pose %d attempt %d: %s", i, attempt + 1, s.problem)
    assert s is not None
    return _record(i, P, s, t)
