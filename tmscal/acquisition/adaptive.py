"""Adaptive acquisition: bootstrap a few well-spread poses, then after every pose predict the
coil-placement error and either stop or move to the candidate that buys the largest expected
reduction of it per second of robot time (docs/adaptive.md; the mathematics is
:mod:`tmscal.calib.adaptive`, docs/methods.md).

The guarantees of the plan loop (:mod:`tmscal.acquisition.run`) hold, through the same code:

* The candidates are THE PLAN of the config with ``pool`` poses, regenerated from the session
  header on ``--resume``; every one is checked against the safety envelope before anything
  moves, and every chosen pose goes through ``Robot.move_to`` and its checks again.
* One fsynced session line per pose, index = order of acquisition (0, 1, 2 …); the line
  records ``pool`` (the candidate's index) and ``robot_s`` (robot time by phase). Ctrl-C
  (``should_stop``) finishes the pose in flight; device faults reconnect; a robot fault stops
  resumably; skipped poses are counted and watched as in a plan run.
* Nothing of the run's state lives outside the session file: the bootstrap, the prediction,
  the next choice (from the last commanded pose, with the robot time measured so far) and the
  stopping decision are re-derived from the recorded poses, so a resumed run continues
  exactly as the uninterrupted run would have from the same data.

Poses: base_from_flange (A), tracker_from_marker (B), tracker_from_probe (C); 4×4 mm; robot
time in seconds.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..calib.adaptive import (
    AdaptiveSettings,
    Prediction,
    bootstrap_indices,
    candidate_cost_s,
    choose_next,
    predict,
    stop_reason,
)
from ..config import RigConfig
from ..drivers.base import ConfigError, SafetyError
from ..errors import CalibrationError, SessionError
from ..session import PoseRecord, SessionWriter, make_header
from ..solving.predict import (
    PHASES,
    adaptive_header,
    prediction_inputs,
    robot_time_of,
    settings_from_header,
)
from .devices import envelope_for
from .plan import PlanSpec, check_plan
from .run import (
    AcquisitionStopped,
    _check_resume,
    _check_robot_where_run_stopped,
    _Devices,
    _pose_with_reconnect,
    _save_pose,
    _valid_or_skipped,
    open_new_run,
    resume_command,
)
from .settings import SamplingSettings as _Settings
from .settings import sampling_settings as _settings
from .skips import SkipWatch

log = logging.getLogger(__name__)

__all__ = ["AdaptiveResult", "acquire_adaptive", "settings_for", "SEM_FRACTION",
           "stop_message"]

#: samples by need: a pose is sampled until the standard error of every body's mean position
#: is at most this fraction of ``target_mm`` (with the sampling section's floor and cap). At
#: 0.2 the averaged measurement noise adds at most ~2 % (1 + 0.2²) to a target-sized error.
SEM_FRACTION = 0.2


@dataclass
class AdaptiveResult:
    """What an adaptive run did. ``recorded`` / ``skipped``: poses in the session (usable /
    skipped); ``new_poses`` in this run; ``stopped``: Ctrl-C before a decision; ``faults``
    recovered; ``elapsed_s`` wall time; ``stop`` "target", "max_poses" or "pool" (None when
    stopped early) with ``message`` saying why; ``prediction`` the last one (None before the
    bootstrap is complete); ``robot_time_s`` {moving, settling, sampling, total} over the
    whole session (s); ``settings``; ``notes`` (settings taken from the session header)."""

    path: Path
    recorded: int
    skipped: int
    new_poses: int
    stopped: bool
    faults: int
    elapsed_s: float
    stop: str | None
    message: str
    prediction: Prediction | None
    robot_time_s: dict[str, float]
    settings: AdaptiveSettings
    notes: list[str] = field(default_factory=list)

    @property
    def poses_used(self) -> int:
        """Usable poses the calibration rests on."""
        return self.recorded


def settings_for(cfg: RigConfig, **overrides: Any) -> AdaptiveSettings:
    """AdaptiveSettings from the config's ``adaptive:`` section, keyword overrides (not None)
    winning; ConfigError naming the key (or the option) when they do not fit together."""
    vals = dataclasses.asdict(cfg.adaptive)
    given = {k: v for k, v in overrides.items() if v is not None}
    vals.update(given)
    try:
        return AdaptiveSettings(**vals)
    except ValueError as e:
        opts = ", ".join(f"--{k.replace('_', '-')} {v:g}" for k, v in given.items())
        raise ConfigError(f"{cfg.path}: key 'adaptive'{' with ' + opts if opts else ''}: {e}"
                          f" (pool {vals['pool']}, max_poses {vals['max_poses']})") from None


def stop_message(reason: str | None, pred: Prediction | None, settings: AdaptiveSettings,
                 n_poses: int) -> str:
    """The one line that says why an adaptive run stopped (or that it did not)."""
    conf = f"{settings.confidence * 100:g} %"
    got = "no prediction" if pred is None else f"predicted {pred.coil_mm:.3g} mm"
    if reason == "target" and pred is not None:
        return (f"predicted coil-placement error {pred.coil_mm:.3g} mm ≤ target "
                f"{settings.target_mm:g} mm at {conf}")
    if reason == "max_poses":
        return (f"reached max_poses {settings.max_poses} with {got} > target "
                f"{settings.target_mm:g} mm at {conf}")
    if reason == "pool":
        return (f"every candidate of the pool was tried ({n_poses} poses) with {got} > "
                f"target {settings.target_mm:g} mm at {conf}")
    return f"not finished: {n_poses} poses, {got} (target {settings.target_mm:g} mm at {conf})"


# --- state: everything is re-derived from the session's records ---------------------------

@dataclass
class _State:
    """The run so far, from the session's records in index order."""

    records: list[PoseRecord]
    used: int
    taken: set[int]
    here: np.ndarray
    next_index: int

    @classmethod
    def of(cls, poses: list[PoseRecord], p0: np.ndarray) -> _State:
        recs = sorted(poses, key=lambda p: p.index)
        used = sum(p.skipped is None and p.C is not None for p in recs)
        taken = {int(p.pool) for p in recs if p.pool is not None}
        last = next((p.commanded for p in reversed(recs) if p.commanded is not None), None)
        return cls(recs, used, taken, p0 if last is None else np.asarray(last),
                   max((p.index for p in recs), default=-1) + 1)


def _pose_overhead_s(records: list[PoseRecord], st: _Settings, rate_hz: float) -> float:
    """Robot time per pose besides the move (s): the mean settling + sampling time measured
    so far; before the first pose a prior from the sampling settings (``settle_s``, the upper
    bound of the wait, plus the full sample count at the tracker's frame rate)."""
    got = [p.robot_s for p in records if p.robot_s]
    if got:
        return float(np.mean([r.get("settling", 0.0) + r.get("sampling", 0.0) for r in got]))
    return st.settle_s + st.samples / max(rate_hz, 1.0)


def _costs(pool: np.ndarray, s: _State, cfg: RigConfig, st: _Settings) -> np.ndarray:
    """Seconds of robot time per candidate: the trapezoidal move from the last commanded pose
    (tmscal.motion, the robot's speed and acceleration) + the per-pose overhead."""
    assert cfg.robot is not None and cfg.tracker is not None
    extra = _pose_overhead_s(s.records, st, cfg.tracker.frame_rate_hz)
    return candidate_cost_s(s.here, pool, cfg.robot.speed_mm_s, cfg.robot.accel_mm_s2, extra)


def _decide(s: _State, pool: np.ndarray, p0: np.ndarray, settings: AdaptiveSettings,
            cfg: RigConfig, st: _Settings, session: Any
            ) -> tuple[str | None, int | None, Prediction | None, dict[str, Any]]:
    """(stop reason, next pool index, prediction, info) from the state alone: bootstrap
    poses first (more when some were skipped), then predict → stop_reason → choose_next."""
    available = np.ones(len(pool), dtype=bool)
    available[list(s.taken)] = False
    n_boot = settings.bootstrap_poses(2)
    pred = None
    if s.used >= n_boot:
        A, B, C, opts = prediction_inputs(session.poses, session.bodies)
        try:
            pred = predict(A, B, C, pool[:settings.region], settings, **opts)
        except (CalibrationError, np.linalg.LinAlgError) as e:  # degenerate: spread further
            log.warning("no prediction from %d poses yet (%s)", s.used, e)
        if pred is not None:
            reason = stop_reason(pred, len(s.records), settings)
            if reason:
                return reason, None, pred, {}
    if len(s.records) >= settings.max_poses:
        return "max_poses", None, pred, {}
    if not available.any():
        return "pool", None, pred, {}
    if pred is None:
        # greedy farthest point is prefix-consistent: a longer list starts with the same poses,
        # so skipped bootstrap poses are replaced by the next well-spread ones
        boot = bootstrap_indices(pool, min(len(pool), n_boot + len(s.taken)), p0)
        j = next((i for i in boot if available[i]), int(np.argmax(available)))
        return None, j, None, {"bootstrap": True}
    j, info = choose_next(pred, pool, available, _costs(pool, s, cfg, st))
    return None, int(j), pred, dict(info)


# --- start or resume ----------------------------------------------------------------------

def _new_run(cfg: RigConfig, out: Path, dev: _Devices, settings: AdaptiveSettings,
             samples: int | None) -> tuple[PlanSpec, np.ndarray, Any, _Settings]:
    spec, pool, envelope = open_new_run(cfg, out, dev, settings.pool)
    st = _settings(cfg, None, samples)
    _by_need(st, settings)
    return spec, pool, envelope, st


def _by_need(st: _Settings, settings: AdaptiveSettings) -> None:
    """Samples by need (``SEM_FRACTION`` × target) unless the sampling section sets sem_mm;
    only where the sampling settings know sem_mm."""
    if hasattr(st, "sem_mm") and st.sem_mm is None:
        st.sem_mm = SEM_FRACTION * settings.target_mm


def _check_pool_poses(session: Any, pool: np.ndarray) -> None:
    """Every recorded pose of an adaptive session names a pool pose (``pool``) that is
    distinct from the others; its commanded pose is checked against it by ``_check_resume``."""
    seen: set[int] = set()
    for rec in session.poses:
        j = rec.pool
        if j is None or j >= len(pool) or j in seen:
            what = ("names no pool pose" if j is None else
                    f"names pool pose {j} of {len(pool)}" if j >= len(pool) else
                    f"repeats pool pose {j}")
            raise SessionError(f"{session.path}: pose {rec.index} {what}: not an adaptive "
                               "session of this pool; refusing to resume")
        seen.add(j)


def _resume_run(cfg: RigConfig, out: Path, dev: _Devices, overrides: dict[str, Any],
                samples: int | None
                ) -> tuple[SessionWriter, PlanSpec, np.ndarray, Any, _Settings,
                           AdaptiveSettings, list[str]]:
    writer = SessionWriter.resume(out)
    try:
        header = writer.session.header
        settings, notes = settings_from_header(header, settings_for(cfg), overrides)
        spec = PlanSpec.from_header(header)
        if spec.n != settings.pool:
            raise SessionError(f"{out}: the header's plan has {spec.n} poses but its adaptive "
                               f"pool {settings.pool}; refusing to resume")
        pool = spec.poses()
        _check_pool_poses(writer.session, pool)
        expected = np.tile(np.eye(4), (max((r.index for r in writer.session.poses),
                                            default=-1) + 1, 1, 1))
        for r in writer.session.poses:
            expected[r.index] = pool[r.pool]
        _check_resume(cfg, writer.session, spec, expected)
        envelope = envelope_for(cfg, spec.p0)
        check_plan(pool, envelope)
        dev.open(envelope)
        st = _settings(cfg, header, samples)
        recorded_target = header["adaptive"].get("target_mm")
        if (cfg.sampling.sem_mm is None and isinstance(recorded_target, float)
                and st.sem_mm == SEM_FRACTION * recorded_target):  # the run's own: no news
            st.notes = [n for n in st.notes if not n.startswith("sampling.sem_mm ")]
        notes = st.notes + notes
        summary = writer.session.damage_summary()
        if summary:
            notes.append(f"{out}: {summary} (those poses are not acquired again)")
    except BaseException:
        writer.close()
        raise
    return writer, spec, pool, envelope, st, settings, notes


def _create(out: Path, cfg: RigConfig, dev: _Devices, spec: PlanSpec, st: _Settings,
            settings: AdaptiveSettings) -> SessionWriter:
    """A new session whose header records the plan (the pool), the sampling settings and
    the adaptive settings beside them."""
    assert dev.robot is not None and dev.tracker is not None
    header = make_header(
        dev.tracker.tools, config=cfg.raw,
        devices={"robot": dev.robot.identity(), "tracker": dev.tracker.identity()},
        plan=spec.to_header(), sampling=st.to_header(), adaptive=adaptive_header(settings))
    return SessionWriter.create(out, header)


def _check_where(dev: _Devices, s: _State, pool: np.ndarray, nxt: int, p0: np.ndarray,
                 envelope: Any, out: Path, resumed: bool) -> None:
    """Before the first move of a run: the arm is inside the envelope and, on a resume,
    near P0 or the path from the last commanded pose to the next choice."""
    assert dev.robot is not None
    here = dev.robot.flange_pose()
    if resumed:  # the arm rests at the last commanded pose or is on its way to the next
        path = np.stack([s.here, pool[nxt]] if s.records else [pool[nxt]])
        _check_robot_where_run_stopped(here, path, p0, {0} if s.records else set(), out)
    v = envelope.violations(here)
    if v:
        raise SafetyError(f"the robot is at {np.round(here[:3, 3], 1).tolist()} mm, "
                          f"outside the safety envelope around P0 ({'; '.join(v)}); "
                          "move it near P0 first. Nothing was moved.")


# --- the loop ---------------------------------------------------------------------------------

class _PhaseClock:
    """Robot time by phase from the loop's phase reports: each report closes the previous
    phase; ``take()`` closes the last and returns {phase: s} for the pose. Phases outside
    ``PHASES`` (reconnecting) are not robot time. ``clock``: monotonic seconds."""

    def __init__(self, forward: Callable[[int, str], None] | None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.forward = forward
        self.clock = clock
        self.spent: dict[str, float] = {}
        self.phase: str | None = None
        self.t = 0.0

    def __call__(self, i: int, name: str) -> None:
        self._close(self.clock())
        self.phase = name
        if self.forward:
            self.forward(i, name)

    def _close(self, now: float) -> None:
        if self.phase in PHASES:
            self.spent[self.phase] = self.spent.get(self.phase, 0.0) + now - self.t
        self.phase, self.t = None, now

    def take(self) -> dict[str, float]:
        self._close(self.clock())
        out = {k: round(self.spent.get(k, 0.0), 6) for k in PHASES}
        self.spent = {}
        return out


@dataclass
class _Run:
    """What one adaptive run works with once started: the devices, the session, the pool and
    its envelope, the sampling and adaptive settings, and the robot-time clock."""

    cfg: RigConfig
    out: Path
    dev: _Devices
    writer: SessionWriter
    spec: PlanSpec
    pool: np.ndarray
    envelope: Any
    st: _Settings
    settings: AdaptiveSettings
    clock: _PhaseClock
    hint: str
    t0: float
    t_offset: float

    def measure(self, s: _State, j: int, watch: SkipWatch, sleep: Callable[[float], None],
                on_pose: Callable[[int, int, PoseRecord], None] | None) -> int:
        """Pool pose j as session pose ``s.next_index``: moved to through ``Robot.move_to``,
        settled, sampled (reconnecting after device faults), saved with its pool index and
        robot time. Returns the device faults recovered."""
        session = self.writer.session
        rec, faults = _pose_with_reconnect(
            self.dev, self.cfg, self.envelope, s.next_index, self.pool[j], self.st, sleep,
            lambda: self.t_offset + time.monotonic() - self.t0,
            lambda: f"The session {self.out} holds {len(session.poses)} poses; {self.hint}",
            self.clock)
        rec = _valid_or_skipped(rec)
        rec.pool, rec.robot_s = j, self.clock.take()
        report = None if on_pose is None else (  # done = poses in the session
            lambda d, t, r: on_pose(len(session.poses), self.settings.max_poses, r))
        _save_pose(self.writer, rec, watch, s.next_index + 1, report, self.hint)
        return faults


def _start(cfg: RigConfig, out: Path, dev: _Devices, resume: bool,
           settings: AdaptiveSettings | None, overrides: dict[str, Any], samples: int | None,
           on_phase: Callable[[int, str], None] | None, hint: str, t0: float
           ) -> tuple[_Run, list[str]]:
    """Start a new run (settings: given, else the config's) or resume one (the header's)."""
    if resume:
        writer, spec, pool, envelope, st, settings, notes = _resume_run(cfg, out, dev,
                                                                        overrides, samples)
    else:
        settings = settings or settings_for(cfg)
        spec, pool, envelope, st = _new_run(cfg, out, dev, settings, samples)
        notes = list(st.notes)
        writer = _create(out, cfg, dev, spec, st, settings)
    t_offset = max((p.time for p in writer.session.poses), default=0.0)
    return _Run(cfg, out, dev, writer, spec, pool, envelope, st, settings,
                _PhaseClock(on_phase), hint, t0, t_offset), notes


def acquire_adaptive(cfg: RigConfig, output: str | Path, *,
                     settings: AdaptiveSettings | None = None, resume: bool = False,
                     overrides: dict[str, Any] | None = None, samples: int | None = None,
                     tracker_port: str | None = None, robot_host: str | None = None,
                     robot_port: int | None = None,
                     on_pose: Callable[[int, int, PoseRecord], None] | None = None,
                     on_start: Callable[[int, int, int], None] | None = None,
                     on_phase: Callable[[int, str], None] | None = None,
                     on_predict: Callable[[Prediction, dict[str, Any]], None] | None = None,
                     should_stop: Callable[[], bool] = lambda: False,
                     sleep: Callable[[float], None] = time.sleep) -> AdaptiveResult:
    """Run (or resume) an adaptive acquisition into session file ``output``.

    ``settings`` for a new run (default: the config's ``adaptive:`` section); on a resume the
    session header's settings, with ``overrides`` ({target_mm, confidence, max_poses,
    bootstrap}: not None wins, noted in ``AdaptiveResult.notes``). ``on_start(done, max_poses,
    skipped)``, ``on_phase(i, phase)``, ``on_pose(done, max_poses, record)`` as in
    ``run.acquire``; ``on_predict(prediction, info)`` after each prediction (info: the stop
    reason or the next choice with its gain, cost (s) and criterion). Raises SafetyError
    (nothing moved), ConfigError, SessionError, or AcquisitionStopped (session intact,
    resumable; the message says how)."""
    out = Path(output)
    if cfg.tracker is None or not {"marker", "probe"} <= set(cfg.tracker.tools):
        raise ConfigError(f"{cfg.path}: key 'tracker.tools': adaptive acquisition predicts the "
                          "coil placement: name the marker tool 'marker' and the probe 'probe'")
    t0 = time.monotonic()
    dev = _Devices(cfg, tracker_port, robot_host, robot_port)
    run: _Run | None = None
    faults = new = 0
    clean = False
    hint = "resume with: " + resume_command(cfg.path, out, tracker_port, robot_host)
    try:
        run, notes = _start(cfg, out, dev, resume, settings, dict(overrides or {}), samples,
                            on_phase, hint, t0)
        for note in notes:
            log.warning("resuming %s with %s", out, note)
        session, p0, settings = run.writer.session, run.spec.p0, run.settings
        s = _State.of(session.poses, p0)
        if on_start:
            on_start(len(s.records), settings.max_poses, len(s.records) - s.used)
        watch = SkipWatch(cfg.run)
        while True:
            reason, j, pred, info = _decide(s, run.pool, p0, settings, cfg, run.st, session)
            if pred is not None and on_predict:
                on_predict(pred, {"stop": reason, "next": j, **info})
            if reason is not None or should_stop():
                break
            assert j is not None
            if new == 0:
                _check_where(dev, s, run.pool, j, p0, run.envelope, out, resume)
            faults += run.measure(s, j, watch, sleep, on_pose)
            new += 1
            s = _State.of(session.poses, p0)
        clean = True
        return AdaptiveResult(
            path=out, recorded=s.used, skipped=len(s.records) - s.used, new_poses=new,
            stopped=reason is None, faults=faults, elapsed_s=time.monotonic() - t0,
            stop=reason, message=stop_message(reason, pred, settings, len(s.records)),
            prediction=pred, robot_time_s=robot_time_of(session.poses), settings=settings,
            notes=notes)
    finally:
        dev.close(stop_robot=not clean)
        if run is not None:
            run.writer.close()


__all__ += ["AcquisitionStopped"]
