"""What a kind of run decides (``Strategy``); the engine (:mod:`.engine`) does the rest.

A strategy says which devices it needs, how a new run is planned and what its header
records, how a resumed run reads its plan back and checks it, which pose comes next and when
to stop, how one pose is measured, and what the result holds. The base class visits a fixed
list of poses (``self.poses``) in order, skipping those already recorded: the plan run
(:mod:`.run`) and the self-calibration run (:mod:`.selfcal`) need nothing else; the adaptive
run (:mod:`.adaptive_run`) chooses its next pose itself.

Poses are base_from_flange 4×4 in mm; times in seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import RigConfig
from ..session import PoseRecord, Session
from .devices import Devices
from .progress import Progress

__all__ = ["Step", "Strategy"]


@dataclass(frozen=True)
class Step:
    """The next pose of a run: its session ``index``, the commanded flange pose ``target``
    (base_from_flange, mm) and the strategy's own ``tag`` (the adaptive run's pool index)."""

    index: int
    target: np.ndarray
    tag: Any = None


class Strategy:
    """The decisions of one kind of run, over ``cfg``. Class attributes: ``sensor`` the
    device beside the robot ("tracker" or "ft"); ``unit`` what one pose is called in
    messages ("pose", "configuration"); ``command`` the CLI command that resumes it;
    ``where_at_start``: the arm's position is checked before the session is written (else
    before the first move, once the first pose is chosen); ``damaged``: what a resume does
    with the poses of damaged lines (for the note), or None for no note; ``moves_in_order``:
    the run goes from P0 through ``poses`` in order by Cartesian moves, so the way between
    them is checked before a new run starts.

    After ``start``/``resume``: ``p0`` (the envelope's centre, base_from_flange mm),
    ``poses`` (every pose the run may command, checked against the envelope before anything
    moves; on a resume the plan re-derived by ``rederive``, not the header's) and ``plan``
    (what ``Progress.planned`` hears) are set."""

    sensor = "tracker"
    unit = "pose"
    command = "acquire"
    where_at_start = True
    damaged: str | None = "their poses are acquired again"
    moves_in_order = False

    def __init__(self, cfg: RigConfig) -> None:
        self.cfg = cfg
        self.p0: np.ndarray = np.eye(4)
        self.poses: np.ndarray = np.zeros((0, 4, 4))
        self.plan: Any = None
        #: what the run says about where its P0 came from (notes of the result)
        self.start_notes: list[str] = []
        #: the end of the refusal when the arm is outside the envelope at the start
        self.where_hint = "move it near P0 first"
        self._done: set[int] = set()
        self._next = 0

    # --- before anything opens ------------------------------------------------------------

    def check(self) -> None:
        """ConfigError when the config lacks what the run needs (nothing is open yet)."""

    def prepare(self) -> None:
        """A new run, before the devices open (e.g. the nominal arm model: ConfigError)."""

    # --- a new run ------------------------------------------------------------------------

    def start_pose(self, dev: Devices) -> np.ndarray:
        """P0 of a new run (base_from_flange, mm): where the flange is."""
        assert dev.robot is not None
        return dev.robot.flange_pose()

    def make_plan(self, dev: Devices, p0: np.ndarray, envelope: Any) -> None:
        """Plan a new run around ``p0`` inside ``envelope``: set ``p0``, ``poses``, ``plan``."""
        raise NotImplementedError

    def header(self) -> dict[str, Any]:
        """The strategy's entries of a new session's header (e.g. plan, sampling), in order."""
        raise NotImplementedError

    # --- a resumed run --------------------------------------------------------------------

    def read(self, session: Session) -> None:
        """Read the plan back from the session's header (and check the records against it
        where that needs no config): set ``p0``, ``poses``, ``plan``; SessionError."""
        raise NotImplementedError

    def rederive(self, session: Session) -> tuple[np.ndarray, str]:
        """The plan of a resumed run RE-DERIVED from the config and what the header records
        of the rig and the run's draw (P0, a seed …), never from the header's poses: the
        poses (n, 4, 4) base_from_flange mm, and what they were derived from (for messages).
        The engine compares them with the header's (``resume.check_same_plan``) and runs
        them. SessionError naming a setting of the header that the config contradicts."""
        raise NotImplementedError

    def planned_pose(self, rec: PoseRecord) -> np.ndarray | None:
        """Where the plan commands recorded pose ``rec`` (base_from_flange mm; None: the plan
        does not say), for ``resume.check_recorded``."""
        return self.poses[rec.index] if 0 <= rec.index < len(self.poses) else None

    # --- both -----------------------------------------------------------------------------

    def settings(self, header: dict[str, Any] | None) -> list[str]:
        """Settle the measurement settings, the config's for a new run (``header`` None),
        else the header's; return the notes (settings taken from the header or the command
        line)."""
        return []

    def begin(self, session: Session) -> None:
        """The run is about to start its loop on ``session``."""
        self._done = session.indices()
        self._next = 0

    def tally(self, session: Session) -> tuple[int, int, int]:
        """(done, total, skipped) for the progress display: poses of the plan in the
        session, the plan's length, and how many of them were skipped."""
        total = len(self.poses)
        recs = [p for p in session.poses if p.index < total]
        return (len(session.indices() & set(range(total))), total,
                sum(p.skipped is not None for p in recs))

    def next(self, session: Session, progress: Progress) -> Step | None:
        """The next pose to measure, or None when the run is complete."""
        while self._next < len(self.poses) and self._next in self._done:
            self._next += 1
        if self._next >= len(self.poses):
            return None
        i = self._next
        self._next += 1
        return Step(i, self.poses[i])

    def where_path(self, session: Session, step: Step | None) -> tuple[np.ndarray, set[int]]:
        """(poses, recorded indices) between which a resumed run's arm may rest (see
        ``resume.check_where_run_stopped``); ``step`` is the first pose (None at start)."""
        return self.poses, session.indices()

    def measure(self, dev: Devices, step: Step, t: float, phase: Callable[[str], None],
                sleep: Callable[[float], None]) -> PoseRecord:
        """Move to ``step.target``, settle, measure; the record at session time ``t`` (s).
        ``phase`` hears "moving", "settling", "sampling". DeviceError → the engine
        reconnects and calls it again."""
        raise NotImplementedError

    def finish(self, rec: PoseRecord, step: Step, robot_s: dict[str, float]) -> PoseRecord:
        """The record as saved (the adaptive run adds its pool index and the robot time by
        phase ``robot_s``)."""
        return rec

    def result_fields(self, session: Session) -> dict[str, Any]:
        """The result's counts: recorded (usable) and skipped poses of the plan, total."""
        total = len(self.poses)
        recs = [p for p in session.poses if p.index < total]
        ok = sum(p.skipped is None for p in recs)
        return {"recorded": ok, "skipped": len(recs) - ok, "total": total}
