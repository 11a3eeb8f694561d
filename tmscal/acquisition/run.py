"""The plan run (``tmscal acquire``): every pose of the config's plan, in order, each moved to,
settled and sampled by the tracker (:mod:`.sample`), through the one engine (:mod:`.engine`:
devices, reconnect, stop, resume, the session file, progress).

* On ``resume`` the plan is re-derived from the config's plan section around the P0 (and
  with the length) the session header records, so the run continues the same plan and skips
  the indices already recorded — also after a crash (each pose is one fsynced line; a torn
  last line is cut off). The header's plan (kind, seed, ranges, P0) must be the config's and
  reproduce every commanded pose already recorded.
* A pose whose bodies were not seen well enough is sampled once more (moving again), then
  recorded as skipped with the reason.
* With a force-torque sensor in the config (``ft``), each pose also records the averaged
  wrench and its spread (``ft.samples`` readings after the tracker's, the same settle;
  :func:`.sample.sample_wrench`), for the wrench rows of ``tmscal solve --kinematics
  estimate`` (docs/kinematics.md); a sensor fault is a device fault like any other.
* ``PlanStrategy`` is also the adaptive run's base (:mod:`.adaptive_run`): its candidates are
  this plan with ``adaptive.pool`` poses, measured the same way.

Poses: base_from_flange (A), tracker_from_marker (B), tracker_from_probe (C); 4×4 mm.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..config import RigConfig
from ..drivers.base import ConfigError
from ..errors import SessionError
from ..poses import JOINTS_KIND
from ..safety.origin import CalibratedP0
from ..session import PoseRecord, Session
from .devices import Devices, Endpoints, envelope_for
from .engine import AcquireResult, AcquisitionStopped, Engine, valid_or_skipped
from .plan import PlanSpec, joints_spec, plan_poses
from .progress import Progress
from .resume import POSE_TOL_MM, RESUME_HINT, resume_command
from .sample import PoseSample, WrenchSample, sample_pose, sample_wrench
from .settings import SamplingSettings, sampling_settings
from .strategy import Step, Strategy

log = logging.getLogger(__name__)

__all__ = ["AcquisitionStopped", "AcquireResult", "PlanStrategy", "acquire", "resume_command",
           "valid_or_skipped", "measure_tracked", "check_plan_matches"]

_LETTER = {"marker": "B", "probe": "C"}


def _record(i: int, P: np.ndarray, s: PoseSample, t: float,
            w: WrenchSample | None = None) -> PoseRecord:
    """A session line: samples keyed A/B/C as the format says, spreads per body name; the
    wrench and its spread when the run reads a force-torque sensor."""
    samples = {_LETTER.get(k, k): v for k, v in s.samples.items()}
    if w is not None:
        samples["wrench"] = w.n
    return PoseRecord(index=i, A=s.A, B=s.bodies.get("marker"), C=s.bodies.get("probe"),
                      commanded=P, time=t, samples=samples, spread=s.spread,
                      skipped=s.problem,
                      joints_rad=None if s.joints is None else s.joints.tolist(),
                      wrench=None if w is None else w.mean.tolist(),
                      wrench_spread=None if w is None else w.spread.tolist())


def measure_tracked(dev: Devices, i: int, P: np.ndarray, st: SamplingSettings, t: float,
                    phase: Callable[[str], None], sleep: Callable[[float], None]
                    ) -> PoseRecord:
    """Move to pose i (``P``, base_from_flange mm), settle and sample the tracker; a pose
    whose bodies were not seen well enough is sampled once more (moving again), then
    recorded as skipped with the reason. With a force-torque sensor open beside the
    tracker (``dev.wrench``), a usable pose also averages ``ft.samples`` wrench readings
    after the tracker's. ``phase`` hears "moving", "settling", "sampling"; ``t`` is the
    session time (s)."""
    assert dev.robot is not None and dev.tracker is not None
    s: PoseSample | None = None
    for attempt in range(2):
        phase("moving")
        dev.robot.move_to(P)
        s = sample_pose(dev.robot, dev.tracker, st, sleep=sleep, on_phase=phase)
        if s.problem is None:
            break
        log.info("pose %d attempt %d: %s", i, attempt + 1, s.problem)
    assert s is not None
    w = None
    if dev.wrench and s.problem is None:
        assert dev.ft is not None and dev.cfg.ft is not None
        w = sample_wrench(dev.ft, dev.cfg.ft.samples)
    return _record(i, P, s, t, w)


def check_plan_matches(cfg: RigConfig, session: Session, spec: PlanSpec) -> None:
    """Refuse to resume a session into a different plan: the header's plan ``spec`` must be
    the config's (kind, seed, ranges, P0 when the config fixes it). Raises SessionError
    naming the key that differs. (That the recorded commanded poses are the plan's is
    ``resume.check_recorded``.)"""
    where = f"{session.path}"
    want = {"kind": cfg.plan.kind, "seed": cfg.plan.seed, "radius_mm": cfg.plan.radius_mm,
            "rotation_deg": cfg.plan.rotation_deg}
    if spec.joints is not None:
        want |= {"span_deg": cfg.plan.span_deg, "pool": cfg.plan.pool}
        if cfg.plan.arm is not None:
            want["arm"] = cfg.plan.arm
    for k, v in want.items():
        got = getattr(spec.joints, k) if k in ("span_deg", "pool", "arm") else getattr(spec, k)
        if got != v:
            raise SessionError(f"{where}: the session's plan.{k} is {got!r}; {cfg.path} says "
                               f"{v!r}; {RESUME_HINT}")
    if not isinstance(cfg.plan.start, str):
        d = float(np.abs(spec.p0 - np.asarray(cfg.plan.start, dtype=float)).max())
        if not d <= POSE_TOL_MM:
            raise SessionError(f"{where}: the session's P0 differs from the config's "
                               f"plan.start (by up to {d:.3g} mm); {RESUME_HINT}")


class PlanStrategy(Strategy):
    """The config's plan (``plan`` section; ``poses`` overrides its length), sampled by the
    tracker with the sampling settings (``samples`` overrides the count). On a resume the
    plan and the sampling settings are the session header's; a run extended by ``--poses``
    earlier keeps its length unless told otherwise."""

    moves_in_order = True

    def __init__(self, cfg: RigConfig, poses: int | None = None,
                 samples: int | None = None, *, origin: CalibratedP0 | None = None) -> None:
        super().__init__(cfg)
        self.n = poses
        self.samples = samples
        self.spec: PlanSpec | None = None
        self.st: SamplingSettings | None = None
        #: the calibration's P0 the run is made around (``acquire --calib``), or None
        self.origin = origin

    def check(self) -> None:
        cfg = self.cfg
        if cfg.tracker is None or "marker" not in cfg.tracker.tools:
            raise ConfigError(f"{cfg.path}: key 'tracker.tools': name the marker tool 'marker' "
                              "(and the probe 'probe')")

    def start_pose(self, dev: Devices) -> np.ndarray:
        """P0 of a new run (base_from_flange 4×4 mm): ``plan.start`` when the config fixes it
        (with a warning and the distance when ``origin``, the calibration's P0, is
        elsewhere); with "current", ``origin`` when given (``tmscal acquire --calib``, so
        that P0 does not walk from session to session: ``safety.origin``), else the flange
        pose, which the run's notes then state."""
        o, cfg = self.origin, self.cfg
        if not isinstance(cfg.plan.start, str):
            p0 = np.asarray(cfg.plan.start, dtype=float)
            warning = None if o is None else o.elsewhere(p0, f"{cfg.path}'s plan.start",
                                                         "leave plan.start 'current' to run "
                                                         "around the calibration's P0")
            if warning:
                self.start_notes.append("WARNING: " + warning)
            return p0
        if o is not None:
            self.start_notes.append(f"P0 is the calibration's, {o.where()} (origin=), not "
                                    "where the arm was left")
            self.where_hint = ("move it back with: tmscal robot CONFIG --calib CAL --move-to "
                               "p0")
            return np.array(o.pose, dtype=float)
        here = super().start_pose(dev)
        x, y, z = (float(v) for v in here[:3, 3])
        self.start_notes.append(f"P0 is where the flange was at the start, ({x:.1f}, {y:.1f}, "
                                f"{z:.1f}) mm (plan.start: current); give origin=CAL to run "
                                "around the calibration's P0 instead")
        return here

    def _poses(self, spec: PlanSpec) -> np.ndarray:
        """The plan's poses (``plan.plan_poses``; a joints plan inside the config's envelope
        around its P0); a ConfigError names the config."""
        try:
            return plan_poses(spec, envelope_for(self.cfg, spec.p0))
        except ConfigError as e:
            msg = str(e)
            raise ConfigError(msg if msg.startswith(str(self.cfg.path)) else
                              f"{self.cfg.path}: {msg}") from None

    def _use(self, spec: PlanSpec) -> None:
        self.spec, self.p0, self.plan = spec, spec.p0, spec
        self.poses = self._poses(spec)

    def make_plan(self, dev: Devices, p0: np.ndarray, envelope: Any) -> None:
        joints = None
        if self.cfg.plan.kind == JOINTS_KIND:
            assert dev.robot is not None
            joints = joints_spec(self.cfg, dev.robot, p0)
        self._use(PlanSpec.from_config(self.cfg.plan, p0, self.n, joints))

    def read(self, session: Session) -> None:
        header = session.header
        last = max((r.index for r in session.poses), default=-1)
        p_hdr = header.get("plan")
        n0 = p_hdr.get("poses", 0) if isinstance(p_hdr, dict) else 0
        spec = PlanSpec.from_header(header)
        n = self.n or (last + 1 if last + 1 > n0 else None)
        try:
            self._use(spec if n is None else spec.with_n(n))
        except SessionError as e:
            raise SessionError(f"{session.path}: the header's plan: {e}; {RESUME_HINT}") \
                from None

    def rederive(self, session: Session) -> tuple[np.ndarray, str]:
        """The config's plan section around the recorded P0, with the header's length (a
        joints plan: with the header's arm, joints of P0 and controller frame, inside the
        config's envelope)."""
        assert self.spec is not None
        check_plan_matches(self.cfg, session, self.spec)
        joints = self.spec.joints
        if joints is not None:
            # check_plan_matches found the config's span_deg and pool equal to the header's
            span_deg, pool = self.cfg.plan.span_deg, self.cfg.plan.pool
            assert span_deg is not None and pool is not None
            joints = replace(joints, span_deg=span_deg, pool=pool)
        derived = PlanSpec.from_config(self.cfg.plan, self.spec.p0, self.spec.n, joints)
        try:
            poses = self._poses(derived)
        except SessionError as e:
            raise SessionError(f"{session.path}: {e}; {RESUME_HINT}") from None
        return poses, f"{self.cfg.path}'s plan section around the recorded P0"

    def settings(self, header: dict[str, Any] | None) -> list[str]:
        self.st = sampling_settings(self.cfg, header, self.samples)
        return self.st.notes

    def header(self) -> dict[str, Any]:
        assert self.spec is not None and self.st is not None
        return {"plan": self.spec.to_header(), "sampling": self.st.to_header()}

    def measure(self, dev: Devices, step: Step, t: float, phase: Callable[[str], None],
                sleep: Callable[[float], None]) -> PoseRecord:
        assert self.st is not None
        return measure_tracked(dev, step.index, step.target, self.st, t, phase, sleep)


def acquire(cfg: RigConfig, output: str | Path, *, resume: bool = False, replace: bool = False,
            poses: int | None = None, samples: int | None = None,
            tracker_port: str | None = None, robot_host: str | None = None,
            robot_port: int | None = None, progress: Progress | None = None,
            should_stop: Callable[[], bool] = lambda: False,
            sleep: Callable[[float], None] = time.sleep,
            origin: CalibratedP0 | None = None) -> AcquireResult:
    """Run (or resume) an acquisition of the config's plan into session file ``output``.

    ``origin``: a calibration's P0 (``CalibrationFile.p0``) that a new run with
    ``plan.start: current`` is made around instead of the flange's pose (docs/safety.md).

    ``poses``/``samples`` override the config (on a resume, the session header's settings
    are used unless overridden; ``AcquireResult.notes`` says so). ``progress`` hears the
    run (``Progress``); ``should_stop()`` is polled before each pose. ``run.retries`` bounds
    the reconnects for one fault: the count starts again after a pose succeeds. Raises
    SafetyError (nothing moved), ConfigError, SessionError, or AcquisitionStopped (session
    intact, resumable; the message says how)."""
    engine = Engine(cfg, output, resume=resume, replace=replace,
                    endpoints=Endpoints(tracker_port, robot_host, robot_port),
                    should_stop=should_stop, sleep=sleep)
    strategy = PlanStrategy(cfg, poses, samples, origin=origin)
    return engine.run(strategy, progress)
