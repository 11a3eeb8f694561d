"""The one acquisition loop: move → settle → measure → append, for every pose a strategy
chooses (:mod:`.strategy`; the plan run, the adaptive run and the self-calibration run).

The engine owns what every run shares:

* the devices (``Devices``: the robot and a tracker or a force-torque sensor) and the safety
  envelope of the config around P0, which the robot carries; every pose the run may command
  is checked against it before anything moves, and so is where the arm is;
* the session file: a new one's header (the config, the devices' identity, the strategy's
  entries), one fsynced line per pose (a measurement the reader would refuse is recorded as
  skipped with the reason, ``valid_or_skipped``), a torn last line cut off on ``--resume``;
* resume: the session locked, the strategy's plan read back from the header, and the same
  checks for every kind of run (:mod:`.resume`), before anything moves: same drivers and
  bodies; the header's plan equal to the one re-derived from the config and the recorded P0
  and seed (``Strategy.rederive``), which is the one run; every recorded pose commanded where
  that plan puts it; the plan inside the envelope; the arm near P0 or where the run stopped,
  in position and orientation, and inside the envelope;
* a device fault (timeout, corrupt reply, lost connection) is retried with a reconnect, at
  most ``run.retries`` times for one pose; a robot fault (protective or emergency stop)
  stops at once. Either way the run ends with ``AcquisitionStopped`` naming the cause and
  how to resume, the session intact;
* ``should_stop()`` is polled before each pose (the CLI sets it on Ctrl-C): the pose in
  flight is finished, the robot stopped, the session left valid;
* skipped poses are watched over the last ``run.skip_window`` poses (``skips.SkipWatch``): too
  many warn once, far too many stop the run (``AcquisitionStopped``);
* the session's time base (seconds, continued across resumes), the robot time by phase
  (``PhaseClock``), and the reports to one ``Progress``.

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
from ..drivers.base import DeviceError, Envelope, RobotFault, SafetyError
from ..errors import SessionError, TmscalError
from ..session import PoseRecord, Session, SessionWriter, make_header, validate_record
from ..session.outputs import check_not_locked
from ..solving.predict import PHASES
from .devices import Devices, Endpoints, envelope_for
from .plan import check_plan, check_plan_moves
from .progress import Progress
from .resume import (
    check_recorded,
    check_same_plan,
    check_same_rig,
    check_where_run_stopped,
    resume_command,
)
from .skips import SkipWatch
from .strategy import Step, Strategy

log = logging.getLogger(__name__)

__all__ = ["AcquisitionStopped", "AcquireResult", "Engine", "PhaseClock", "valid_or_skipped"]


class AcquisitionStopped(TmscalError):
    """The run stopped before the plan was complete; the session is valid and resumable."""


@dataclass
class AcquireResult:
    """What a run did: the session ``path``; poses ``recorded`` (usable) / ``skipped`` of
    ``total`` planned (an adaptive run: ``max_poses``); ``stopped`` early (Ctrl-C); device
    ``faults`` recovered; wall time ``elapsed_s`` (s); ``new_poses`` in this run; ``notes``
    (settings a resumed run took from the session header or the command line).

    An adaptive run adds: ``stop`` "target", "max_poses" or "pool" (None when stopped early)
    with ``message`` saying why; ``prediction`` the last one (None before the bootstrap is
    complete); ``robot_time_s`` {moving, settling, sampling, total} over the whole session
    (s); its ``settings`` (``AdaptiveSettings``)."""

    path: Path
    recorded: int
    skipped: int
    total: int
    stopped: bool
    faults: int
    elapsed_s: float
    new_poses: int
    notes: list[str] = field(default_factory=list)
    stop: str | None = None
    message: str = ""
    prediction: Any = None
    robot_time_s: dict[str, float] | None = None
    settings: Any = None

    @property
    def poses_used(self) -> int:
        """Usable poses the calibration rests on."""
        return self.recorded


def valid_or_skipped(rec: PoseRecord) -> PoseRecord:
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


class PhaseClock:
    """Robot time by phase from the phase reports of a run: each report closes the previous
    phase and is passed on to ``forward`` (a Progress); ``take()`` closes the last phase and
    returns {phase: s} for the pose. Phases outside ``PHASES`` (reconnecting) are not robot
    time. ``clock``: monotonic seconds."""

    def __init__(self, forward: Progress | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.forward = forward
        self.clock = clock
        self.spent: dict[str, float] = {}
        self.phase: str | None = None
        self.t = 0.0

    def __call__(self, i: int, name: str) -> None:
        self._close(self.clock())
        self.phase = name
        if self.forward is not None:
            self.forward.phase(i, name)

    def _close(self, now: float) -> None:
        if self.phase in PHASES:
            self.spent[self.phase] = self.spent.get(self.phase, 0.0) + now - self.t
        self.phase, self.t = None, now

    def take(self) -> dict[str, float]:
        """{moving, settling, sampling: s} since the last ``take`` (0 for a phase not seen)."""
        self._close(self.clock())
        out = {k: round(self.spent.get(k, 0.0), 6) for k in PHASES}
        self.spent = {}
        return out


class Engine:
    """Runs a strategy on the rig of ``cfg`` into the session file ``output`` (``resume``:
    continue it; ``replace``: a new run over an existing session, which is replaced only when
    the new header is written, after the devices answered and the plan was checked, so a run
    that cannot start leaves it as it was). ``endpoints`` override the config's device
    addresses; ``should_stop`` is polled before each pose; ``sleep`` waits (s)."""

    def __init__(self, cfg: RigConfig, output: str | Path, *, resume: bool = False,
                 replace: bool = False, endpoints: Endpoints | None = None,
                 should_stop: Callable[[], bool] = lambda: False,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.cfg = cfg
        self.out = Path(output)
        self.resume = resume
        self.replace = replace and not resume
        self.endpoints = endpoints or Endpoints()
        self.should_stop = should_stop
        self.sleep = sleep
        self.hint = ""  # "resume with: …", once the strategy is known
        self._t0 = time.monotonic()

    def run(self, strategy: Strategy, progress: Progress | None = None) -> AcquireResult:
        """Run (or resume) ``strategy`` to its end, a stop request, or an error. Raises
        SafetyError (nothing moved), ConfigError, SessionError, or AcquisitionStopped
        (session intact, resumable; the message says how)."""
        progress = progress or Progress()
        strategy.check()
        self._t0 = time.monotonic()
        ep = self.endpoints
        self.hint = "resume with: " + resume_command(
            self.cfg.path, self.out, ep.tracker_port, ep.robot_host, ep.ft_address,
            strategy.command)
        dev = Devices(self.cfg, strategy.sensor, ep)
        writer: SessionWriter | None = None
        clean = False
        try:
            if self.resume:
                writer = SessionWriter.resume(self.out)
                envelope, notes = self._resume(strategy, dev, writer.session)
            else:
                envelope, notes = self._new(strategy, dev)
            for note in notes:  # a new run's notes end its summary (the result's notes)
                (log.warning if self.resume else log.info)(
                    "%s %s: %s", "resuming" if self.resume else "recording", self.out, note)
            if writer is None:
                header = make_header(dev.bodies, config=self.cfg.raw,
                                     devices=dev.identities(), **strategy.header())
                writer = SessionWriter.create(self.out, header, overwrite=self.replace)
            result = self._loop(strategy, progress, dev, envelope, writer, notes)
            clean = True
        finally:
            dev.close(stop_robot=not clean)
            if writer is not None:
                writer.close()
        progress.finished(result)
        return result

    # --- start ----------------------------------------------------------------------------

    def _new(self, strategy: Strategy, dev: Devices) -> tuple[Envelope, list[str]]:
        """A new run (SessionError if the file exists, unless ``replace``): open the devices
        with the config's caps and box, take P0, plan, check every pose against the envelope
        around P0 before anything moves; the robot then carries that envelope."""
        if self.replace:
            check_not_locked(self.out)
        elif self.out.exists():
            raise SessionError(f"{self.out}: already exists; resume it (resume=True) or "
                               "choose another file")
        strategy.prepare()
        dev.open(envelope_for(self.cfg, None))  # speed caps and the box, until P0 is known
        assert dev.robot is not None
        p0 = strategy.start_pose(dev)
        envelope = envelope_for(self.cfg, p0)
        strategy.make_plan(dev, p0, envelope)
        check_plan(strategy.poses, envelope)
        if strategy.moves_in_order:  # the way between the poses, with the controller's law
            _, blocked = check_plan_moves(strategy.poses, envelope, p0, dev.robot.motion_law())
            if blocked:
                raise SafetyError(f"the plan was checked before the run: {blocked[0]}")
        dev.robot.envelope = envelope
        notes = strategy.start_notes + strategy.settings(None)
        if strategy.where_at_start:
            self._check_where(dev, envelope, strategy, None, None)
        return envelope, notes

    def _resume(self, strategy: Strategy, dev: Devices, session: Session
                ) -> tuple[Envelope, list[str]]:
        """A resumed run: the plan read back from the header, re-derived from the config and
        compared with it (the re-derived plan is the one run), the records checked against
        it, every pose against the envelope; then the devices open."""
        strategy.read(session)
        check_same_rig(self.cfg, session, strategy.sensor)
        derived, source = strategy.rederive(session)
        check_same_plan(strategy.poses, derived, session.path, strategy.unit, source)
        strategy.poses = derived
        check_recorded(session.poses, strategy.planned_pose, session.path, strategy.unit)
        envelope = envelope_for(self.cfg, strategy.p0)
        check_plan(strategy.poses, envelope)
        dev.open(envelope)
        notes = strategy.settings(session.header)
        summary = session.damage_summary()
        if summary and strategy.damaged:
            notes.append(f"{self.out}: {summary} ({strategy.damaged})")
        if strategy.where_at_start:
            self._check_where(dev, envelope, strategy, session, None)
        return envelope, notes

    def _check_where(self, dev: Devices, envelope: Envelope, strategy: Strategy,
                     session: Session | None, step: Step | None) -> None:
        """Before the first move: on a resume (``session``) the arm is near P0 or where the
        run stopped, in position and orientation; in any case inside the envelope."""
        assert dev.robot is not None
        here = dev.robot.flange_pose()
        if session is not None:
            path, done = strategy.where_path(session, step)
            check_where_run_stopped(here, path, strategy.p0, done, self.out)
        v = envelope.violations(here)
        if v:
            raise SafetyError(f"the robot is at {np.round(here[:3, 3], 1).tolist()} mm, "
                              f"outside the safety envelope around P0 ({'; '.join(v)}); "
                              f"{strategy.where_hint}. Nothing was moved.")

    # --- the loop -------------------------------------------------------------------------

    def _loop(self, strategy: Strategy, progress: Progress, dev: Devices, envelope: Envelope,
              writer: SessionWriter, notes: list[str]) -> AcquireResult:
        session = writer.session
        progress.planned(strategy.plan)
        t_offset = max((p.time for p in session.poses), default=0.0)
        strategy.begin(session)
        progress.started(*strategy.tally(session))
        watch = SkipWatch(self.cfg.run, sum(p.skipped is not None for p in session.poses))
        clock = PhaseClock(progress)
        faults = new = 0
        stopped = False
        while True:
            step = strategy.next(session, progress)
            if step is None:
                break
            if self.should_stop():
                stopped = True
                break
            if new == 0 and not strategy.where_at_start:
                self._check_where(dev, envelope, strategy, session if self.resume else None,
                                  step)
            rec, n = self._measure(strategy, dev, envelope, step, clock, session,
                                   lambda: t_offset + time.monotonic() - self._t0)
            faults += n
            rec = strategy.finish(valid_or_skipped(rec), step, clock.take())
            self._save(strategy, progress, writer, rec, watch)
            new += 1
        fields = strategy.result_fields(session)
        return AcquireResult(path=self.out, stopped=stopped, faults=faults,
                             elapsed_s=time.monotonic() - self._t0, new_poses=new,
                             notes=notes, **fields)

    def _state(self, strategy: Strategy, session: Session) -> str:
        """What the session holds and how to resume (the end of every stop message)."""
        return f"The session {self.out} holds {len(session.poses)} {strategy.unit}s; {self.hint}"

    def _measure(self, strategy: Strategy, dev: Devices, envelope: Envelope, step: Step,
                 clock: PhaseClock, session: Session, now: Callable[[], float]
                 ) -> tuple[PoseRecord, int]:
        """One pose, reconnecting after device faults: at most ``run.retries`` reconnects
        for it (the count is per fault, not per run). Returns the record and the faults
        recovered. A robot fault, a failed reconnect or too many faults raise
        AcquisitionStopped."""
        what, i, retries = strategy.unit, step.index, self.cfg.run.retries
        faults = 0
        while True:
            try:
                return strategy.measure(dev, step, now(), lambda name: clock(i, name),
                                        self.sleep), faults
            except RobotFault as e:
                raise AcquisitionStopped(
                    f"{what} {i}: robot fault: {e}. {self._state(strategy, session)} (clear "
                    "the fault at the robot first)") from e
            except DeviceError as e:
                faults += 1
                if faults > retries:
                    raise AcquisitionStopped(f"{what} {i}: {e} (after {retries} reconnects). "
                                             f"{self._state(strategy, session)}") from e
                log.warning("%s %d: %s; reconnecting (%d of %d)", what, i, e, faults, retries)
                clock(i, "reconnecting")
                dev.close(stop_robot=True)
                self.sleep(self.cfg.run.reconnect_wait_s)
                try:
                    dev.open(envelope)
                except DeviceError as e2:
                    raise AcquisitionStopped(
                        f"{what} {i}: reconnect failed ({e2}) after: {e}. "
                        f"{self._state(strategy, session)}") from e2

    def _save(self, strategy: Strategy, progress: Progress, writer: SessionWriter,
              rec: PoseRecord, watch: SkipWatch) -> None:
        """Append pose ``rec``, report it, and apply the skip thresholds: a warning is
        logged; past ``run.stop_skip_share`` the run stops with AcquisitionStopped."""
        writer.append(rec)
        done, total, _ = strategy.tally(writer.session)
        progress.pose(done, total, rec)
        warning, stop_reason = watch.add(rec)
        if warning:
            log.warning("%s %d: %s", strategy.unit, rec.index, warning)
        if stop_reason:
            raise AcquisitionStopped(f"{strategy.unit} {rec.index}: {stop_reason}. "
                                     f"{self._state(strategy, writer.session)}")
