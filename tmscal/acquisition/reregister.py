"""Re-registration at the rig (``tmscal acquire CONFIG --calib CAL --update z -o TODAY``,
docs/lab-day.md): a few well-spread poses around the calibration's P0, measured one at a time
until the update of only the named transforms (``calib.diagnose.update``: maximum likelihood
of them, the rest and any arm kept) predicts a coil placement within the target, then the
session is left for ``solve TODAY --calib CAL --update z -o NEW``, which the command runs.

The poses: the config's plan drawn with ``pool`` candidates around the calibration's P0 (the
run's P0, ``safety.origin``), taken in the greedy farthest-point order of
``calib.prediction.bootstrap_indices`` (each next pose the one farthest from those already
taken, in position and rotation), so that any first k of them are well spread; at most
``max_poses``; each pose sampled by need as the adaptive run does. The stopping rule, checked
after each pose once the update is determined (``calib.diagnose.min_poses``): the 95th
percentile of the coil-placement error that the update's own uncertainty leaves
(``calib.diagnose.placement_spread``, mm) is ≤ ``target_mm``; an update refused after
``REFUSALS_TO_STOP`` poses in a row (a second change on top of the named one, or residuals
beyond the noise model) stops the run, since more poses of a rig that changed otherwise would
only confirm it. A marker-only run has no coil prediction and takes ``max_poses`` poses.

Frames and units: poses base_from_flange 4×4 mm; errors mm.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..calib import Calibration
from ..calib import diagnose as dg
from ..calib.prediction import bootstrap_indices
from ..config import RigConfig
from ..drivers.base import ConfigError
from ..errors import CalibrationError
from ..poses import JOINTS_KIND
from ..session import PoseRecord, Session
from ..solving.kinematics import session_frames
from ..solving.predict import robot_time_of
from .adaptive_run import SEM_FRACTION
from .devices import Endpoints
from .engine import AcquireResult, Engine
from .progress import Progress
from .run import PlanStrategy
from .strategy import Step

log = logging.getLogger(__name__)

__all__ = ["ReregisterSettings", "ReregisterStrategy", "reregister", "REFUSALS_TO_STOP"]

#: a refused update stops the run when it is refused after this many poses in a row: one
#: refusal from the fewest poses can be noise that the next pose clears (the refusal's test has
#: little redundancy there), two in a row is the rig (measured: benchmarks/reregister_rig.py)
REFUSALS_TO_STOP = 2


@dataclass(frozen=True)
class ReregisterSettings:
    """What to re-register and when to stop: ``names`` (``--update`` names: z, x, y, coil),
    ``target_mm`` (the 95th percentile of the predicted coil-placement error, mm),
    ``max_poses`` (at most), ``pool`` (the candidates drawn from the config's plan)."""

    names: tuple[str, ...]
    target_mm: float = 0.1
    max_poses: int = 10
    pool: int = 200

    def __post_init__(self) -> None:
        dg.blocks_of_update(self.names)  # CalibrationError for unknown names
        if not (np.isfinite(self.target_mm) and self.target_mm > 0):
            raise ValueError(f"target_mm: expected a number > 0, got {self.target_mm!r}")
        if not 2 <= self.max_poses <= self.pool:
            raise ValueError(f"max_poses: expected 2 ≤ max_poses ≤ pool ({self.pool}), got "
                             f"{self.max_poses}")


class ReregisterStrategy(PlanStrategy):
    """The re-registration run (module docstring): the plan's ``pool`` candidates in
    farthest-point order, at most ``max_poses`` of them, until the update of ``names`` of the
    calibration ``cal`` with the noise model ``noise`` predicts ``target_mm``. After the run
    ``stop`` is "target", "max_poses" or "refused" and ``spread`` the last prediction
    ({"mean_mm", "p95_mm"} or None); ``refusal`` the UpdateRefused that stopped it."""

    damaged = None

    def __init__(self, cfg: RigConfig, cal: Calibration, noise: dg.NoiseModel,
                 settings: ReregisterSettings, samples: int | None = None, *,
                 origin: Any = None) -> None:
        super().__init__(cfg, settings.pool, samples, origin=origin)
        self.cal, self.noise, self.rr = cal, noise, settings
        self.stop: str | None = None
        self.spread: dict[str, float] | None = None
        self.refusal: dg.UpdateRefused | None = None
        self.min_n = 0
        self._refused = 0

    def check(self) -> None:
        super().check()
        if self.cfg.plan.kind == JOINTS_KIND:
            raise ConfigError(f"{self.cfg.path}: key 'plan.kind': a re-registration draws its "
                              "poses from an eq14 or sphere plan around the calibration's P0")

    def _use(self, spec: Any) -> None:
        super()._use(spec)
        order = bootstrap_indices(self.poses, min(self.rr.max_poses, len(self.poses)), spec.p0)
        self.poses = self.poses[order]
        with_probe = self.cal.Y is not None and "probe" in (self.cfg.tracker.tools
                                                             if self.cfg.tracker else {})
        self.min_n = dg.min_poses(dg.blocks_of_update(self.rr.names), with_probe)

    def settings(self, header: dict[str, Any] | None) -> list[str]:
        """The config's sampling, by need as in the adaptive run when the sampling section
        sets no ``sem_mm``: each pose until every body's standard error of the mean position
        is ≤ ``SEM_FRACTION`` × the target (docs/adaptive.md, "The robot-time model")."""
        notes = super().settings(header)
        st = self.st
        if header is None and st is not None and st.sem_mm is None:
            st.sem_mm = SEM_FRACTION * self.rr.target_mm
        return notes

    def header(self) -> dict[str, Any]:
        return {**super().header(),
                "reregister": {"update": list(self.rr.names), "target_mm": self.rr.target_mm,
                               "max_poses": self.rr.max_poses, "pool": self.rr.pool,
                               "calibration": str(self.cal.extra.get("source", ""))}}

    def next(self, session: Session, progress: Progress) -> Step | None:
        """The next well-spread pose, or None once the update predicts the target, is
        refused, or ``max_poses`` were measured."""
        used = sum(p.skipped is None for p in session.poses)
        if used >= self.min_n and self._judge(session):
            return None
        step = super().next(session, progress)
        if step is None and self.stop is None:
            self.stop = "max_poses"
        return step

    def _judge(self, session: Session) -> bool:
        """True to stop: the update of the poses so far is refused or meets the target."""
        try:
            ft = dg.update(session_frames(session, self.cal), self.noise, self.rr.names)
        except dg.UpdateRefused as e:
            self._refused += 1
            self.refusal = e
            if self._refused >= REFUSALS_TO_STOP:
                self.stop = "refused"
                return True
            return False
        except (CalibrationError, np.linalg.LinAlgError) as e:  # not determined yet
            log.info("no update from %d poses yet (%s)", len(session.poses), e)
            return False
        self._refused, self.refusal = 0, None
        self.spread = dg.placement_spread(ft)
        if self.spread is not None and self.spread["p95_mm"] <= self.rr.target_mm:
            self.stop = "target"
            return True
        return False

    def finish(self, rec: PoseRecord, step: Step, robot_s: dict[str, float]) -> PoseRecord:
        rec.robot_s = robot_s
        return rec

    def result_fields(self, session: Session) -> dict[str, Any]:
        out = super().result_fields(session)
        out["total"] = len(self.poses)
        sp = self.spread
        if self.stop == "target" and sp is not None:
            msg = (f"the update's predicted coil placement at 95 % is {sp['p95_mm']:.3f} mm ≤ "
                   f"{self.rr.target_mm:g} mm")
        elif self.stop == "refused":
            msg = f"the update was refused: {self.refusal}"
        else:
            msg = (f"reached max_poses {self.rr.max_poses}"
                   + (f" with a predicted {sp['p95_mm']:.3f} mm > {self.rr.target_mm:g} mm"
                      if sp is not None else ""))
        return {**out, "stop": self.stop, "message": msg, "prediction": sp,
                "robot_time_s": robot_time_of(session.poses), "settings": self.rr}


def reregister(cfg: RigConfig, output: Any, cal: Calibration, noise: dg.NoiseModel,
               settings: ReregisterSettings, origin: Any, *, replace: bool = False,
               samples: int | None = None, tracker_port: str | None = None,
               robot_host: str | None = None, robot_port: int | None = None,
               progress: Progress | None = None,
               should_stop: Callable[[], bool] = lambda: False,
               sleep: Callable[[float], None] = time.sleep) -> AcquireResult:
    """Run a re-registration into session file ``output`` around ``origin`` (the
    calibration's P0, ``CalibrationFile.p0``); the result's ``stop``/``message``/
    ``prediction`` say how it ended. Raises as ``run.acquire`` does."""
    engine = Engine(cfg, output, resume=False, replace=replace,
                    endpoints=Endpoints(tracker_port, robot_host, robot_port),
                    should_stop=should_stop, sleep=sleep)
    strategy = ReregisterStrategy(cfg, cal, noise, settings, samples, origin=origin)
    return engine.run(strategy, progress)
