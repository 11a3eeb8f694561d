"""Adaptive acquisition (``tmscal acquire --adaptive``): bootstrap a few well-spread poses, then
after every pose predict the coil-placement error and either stop or move to the candidate
that buys the largest expected reduction of it per second of robot time (docs/adaptive.md;
the mathematics is :mod:`tmscal.calib.prediction`, docs/methods.md).

A strategy of the one engine (:mod:`.engine`), built on the plan run's (:mod:`.run`), so its
guarantees hold through the same code:

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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..calib.prediction import (
    AdaptiveSettings,
    Prediction,
    bootstrap_indices,
    candidate_cost_s,
    choose_next,
    predict,
    stop_reason,
)
from ..config import RigConfig
from ..drivers.base import ConfigError
from ..errors import CalibrationError, SessionError
from ..poses import JOINTS_KIND
from ..safety.origin import CalibratedP0
from ..session import PoseRecord, Session
from ..solving.predict import (
    adaptive_header,
    arm_error_counts,
    model_error_hint,
    prediction_inputs,
    robot_time_of,
    settings_from_header,
)
from .devices import Endpoints
from .engine import AcquireResult, AcquisitionStopped, Engine
from .plan import PlanSpec
from .progress import Progress
from .run import PlanStrategy
from .settings import SamplingSettings, sampling_settings
from .strategy import Step

log = logging.getLogger(__name__)

__all__ = ["AdaptiveStrategy", "acquire_adaptive", "settings_for", "SEM_FRACTION",
           "stop_message", "AcquisitionStopped", "AcquireResult"]

#: samples by need: a pose is sampled until the standard error of every body's mean position
#: is at most this fraction of ``target_mm`` (with the sampling section's floor and cap). At
#: 0.2 the averaged measurement noise adds at most ~2 % (1 + 0.2²) to a target-sized error.
SEM_FRACTION = 0.2


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


def _pose_overhead_s(records: list[PoseRecord], st: SamplingSettings, rate_hz: float) -> float:
    """Robot time per pose besides the move (s): the mean settling + sampling time measured
    so far; before the first pose a prior from the sampling settings (``settle_s``, the upper
    bound of the wait, plus the full sample count at the tracker's frame rate)."""
    got = [p.robot_s for p in records if p.robot_s]
    if got:
        return float(np.mean([r.get("settling", 0.0) + r.get("sampling", 0.0) for r in got]))
    return st.settle_s + st.samples / max(rate_hz, 1.0)


def _costs(pool: np.ndarray, s: _State, cfg: RigConfig, st: SamplingSettings) -> np.ndarray:
    """Seconds of robot time per candidate: the trapezoidal move from the last commanded pose
    (tmscal.motion, the robot's speed and acceleration) + the per-pose overhead."""
    assert cfg.robot is not None and cfg.tracker is not None
    extra = _pose_overhead_s(s.records, st, cfg.tracker.frame_rate_hz)
    return candidate_cost_s(s.here, pool, cfg.robot.speed_mm_s, cfg.robot.accel_mm_s2, extra)


def _decide(s: _State, pool: np.ndarray, p0: np.ndarray, settings: AdaptiveSettings,
            cfg: RigConfig, st: SamplingSettings, session: Any
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
            pred = predict(A, B, C, pool[:settings.region], settings,
                           model_error=arm_error_counts(session), **opts)
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


# --- start or resume -------------------------------------------------------------------------

def _by_need(st: SamplingSettings, settings: AdaptiveSettings) -> None:
    """Samples by need (``SEM_FRACTION`` × target) unless the sampling section sets sem_mm;
    only where the sampling settings know sem_mm."""
    if hasattr(st, "sem_mm") and st.sem_mm is None:
        st.sem_mm = SEM_FRACTION * settings.target_mm


def _check_pool_poses(session: Any, pool: np.ndarray) -> None:
    """Every recorded pose of an adaptive session names a pool pose (``pool``) that is
    distinct from the others; its commanded pose is checked against it by
    ``resume.check_recorded``."""
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


# --- the strategy -----------------------------------------------------------------------------

class AdaptiveStrategy(PlanStrategy):
    """The adaptive run over the config's plan with ``settings.pool`` poses as candidates.
    ``settings`` for a new run (default: the config's ``adaptive:`` section); on a resume
    the session header's, with ``overrides`` ({target_mm, confidence, max_poses,
    bootstrap}: not None wins, noted). ``samples`` overrides the sampling count.

    The arm's position is checked before the first move (the path from the last commanded
    pose to the first choice); the damaged lines of a resumed session are not acquired again
    (their indices are taken)."""

    where_at_start = False
    moves_in_order = False   # it chooses its next pose; each move is checked when planned
    damaged = "those poses are not acquired again"

    def __init__(self, cfg: RigConfig, settings: AdaptiveSettings | None = None,
                 overrides: dict[str, Any] | None = None, samples: int | None = None, *,
                 origin: CalibratedP0 | None = None) -> None:
        super().__init__(cfg, None, samples, origin=origin)
        self.adaptive = settings
        self.overrides = dict(overrides or {})
        self._notes: list[str] = []
        self._s: _State | None = None
        self.reason: str | None = None
        self.pred: Prediction | None = None

    @property
    def pool(self) -> np.ndarray:
        """The candidates: the plan with ``pool`` poses (n, 4, 4) base_from_flange mm."""
        return self.poses

    def check(self) -> None:
        cfg = self.cfg
        if cfg.tracker is None or not {"marker", "probe"} <= set(cfg.tracker.tools):
            raise ConfigError(f"{cfg.path}: key 'tracker.tools': adaptive acquisition predicts "
                              "the coil placement: name the marker tool 'marker' and the probe "
                              "'probe'")
        if cfg.plan.kind == JOINTS_KIND:
            raise ConfigError(f"{cfg.path}: key 'plan.kind': the adaptive run's candidates are "
                              "an eq14 or sphere plan around P0 (its prediction region); a "
                              "joints plan goes with tmscal acquire without --adaptive")

    def prepare(self) -> None:
        self.adaptive = self.adaptive or settings_for(self.cfg)
        self.n = self.adaptive.pool

    def read(self, session: Session) -> None:
        header = session.header
        self.adaptive, self._notes = settings_from_header(header, settings_for(self.cfg),
                                                          self.overrides)
        spec = PlanSpec.from_header(header)
        if spec.n != self.adaptive.pool:
            raise SessionError(f"{session.path}: the header's plan has {spec.n} poses but its "
                               f"adaptive pool {self.adaptive.pool}; refusing to resume")
        self._use(spec)
        _check_pool_poses(session, self.pool)

    def planned_pose(self, rec: PoseRecord) -> np.ndarray | None:
        """The pool pose the record names (``read`` checked that it names a distinct one)."""
        return self.pool[rec.pool] if rec.pool is not None else None

    def settings(self, header: dict[str, Any] | None) -> list[str]:
        assert self.adaptive is not None
        st = sampling_settings(self.cfg, header, self.samples)
        self.st = st
        if header is None:
            _by_need(st, self.adaptive)
            return list(st.notes)
        recorded_target = header["adaptive"].get("target_mm")
        if (self.cfg.sampling.sem_mm is None and isinstance(recorded_target, float)
                and st.sem_mm == SEM_FRACTION * recorded_target):  # the run's own: no news
            st.notes = [n for n in st.notes if not n.startswith("sampling.sem_mm ")]
        return st.notes + self._notes

    def header(self) -> dict[str, Any]:
        assert self.adaptive is not None
        return {**super().header(), "adaptive": adaptive_header(self.adaptive)}

    def tally(self, session: Session) -> tuple[int, int, int]:
        """(poses in the session, max_poses, skipped poses)."""
        assert self.adaptive is not None
        s = _State.of(session.poses, self.p0)
        return len(session.poses), self.adaptive.max_poses, len(s.records) - s.used

    def next(self, session: Session, progress: Progress) -> Step | None:
        """Decide from the records alone; report the prediction; None to stop."""
        assert self.adaptive is not None and self.st is not None
        s = self._s = _State.of(session.poses, self.p0)
        reason, j, pred, info = _decide(s, self.pool, self.p0, self.adaptive, self.cfg,
                                        self.st, session)
        self.reason, self.pred = reason, pred
        if pred is not None:
            progress.predicted(pred, {"stop": reason, "next": j, **info})
        if reason is not None:
            return None
        assert j is not None
        return Step(s.next_index, self.pool[j], tag=j)

    def where_path(self, session: Session, step: Step | None) -> tuple[np.ndarray, set[int]]:
        """The arm rests at the last commanded pose or is on its way to the first choice."""
        assert self._s is not None and step is not None
        s = self._s
        path = np.stack([s.here, step.target] if s.records else [step.target])
        return path, {0} if s.records else set()

    def finish(self, rec: PoseRecord, step: Step, robot_s: dict[str, float]) -> PoseRecord:
        rec.pool, rec.robot_s = step.tag, robot_s
        return rec

    def result_fields(self, session: Session) -> dict[str, Any]:
        assert self.adaptive is not None
        s = _State.of(session.poses, self.p0)
        message = stop_message(self.reason, self.pred, self.adaptive, len(s.records))
        if self.reason in ("max_poses", "pool") and self.pred is not None:
            hint = model_error_hint(session, self.pred, self.adaptive)
            if hint:
                message += f"; the cause is model error, {hint}"
        return {"recorded": s.used, "skipped": len(s.records) - s.used,
                "total": self.adaptive.max_poses, "stop": self.reason,
                "message": message,
                "prediction": self.pred, "robot_time_s": robot_time_of(session.poses),
                "settings": self.adaptive}


def acquire_adaptive(cfg: RigConfig, output: str | Path, *,
                     settings: AdaptiveSettings | None = None, resume: bool = False,
                     replace: bool = False,
                     overrides: dict[str, Any] | None = None, samples: int | None = None,
                     tracker_port: str | None = None, robot_host: str | None = None,
                     robot_port: int | None = None, progress: Progress | None = None,
                     should_stop: Callable[[], bool] = lambda: False,
                     sleep: Callable[[float], None] = time.sleep,
                     origin: CalibratedP0 | None = None) -> AcquireResult:
    """Run (or resume) an adaptive acquisition into session file ``output``; ``origin`` as
    for :func:`.run.acquire` (a calibration's P0 to run around).

    ``settings`` for a new run (default: the config's ``adaptive:`` section); on a resume the
    session header's settings, with ``overrides`` ({target_mm, confidence, max_poses,
    bootstrap}: not None wins, noted in ``AcquireResult.notes``). ``progress`` hears the run
    (``Progress``; ``predicted`` after each prediction); ``total`` is ``max_poses``. The
    result's adaptive fields (stop, message, prediction, robot_time_s, settings) are set.
    Raises SafetyError (nothing moved), ConfigError, SessionError, or AcquisitionStopped
    (session intact, resumable; the message says how)."""
    engine = Engine(cfg, output, resume=resume, replace=replace,
                    endpoints=Endpoints(tracker_port, robot_host, robot_port),
                    should_stop=should_stop, sleep=sleep)
    strategy = AdaptiveStrategy(cfg, settings, overrides, samples, origin=origin)
    return engine.run(strategy, progress)
