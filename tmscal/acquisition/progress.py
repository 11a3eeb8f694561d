"""What a run reports while it goes (``Progress``).

Every kind of run (the plan, the adaptive run, the self-calibration run; :mod:`.engine`)
reports through one ``Progress`` object. The base class does nothing; a display (the CLI's
progress bar, the adaptive prediction lines) overrides what it shows, and ``ProgressGroup``
passes every report to several of them. Indices are session pose indices (0-based).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..session import PoseRecord

__all__ = ["Progress", "ProgressGroup"]


class Progress:
    """The reports of a run, in the order they come; every method is a no-op here.

    ``planned(plan)`` once the plan is known and checked, before anything moves (a
    ``PlanSpec``, or a ``SelfcalPlan`` of joint configurations); ``started(done, total,
    skipped)`` before the first move: ``done`` poses already in the session (a resumed run),
    ``skipped`` of them skipped, ``total`` planned (the adaptive run: ``max_poses``);
    ``phase(i, name)`` as pose ``i`` is "moving", "settling", "sampling" (and "reconnecting"
    after a device fault); ``predicted(prediction, info)`` after each prediction of an
    adaptive run (info: the stop reason or the next choice with its gain, cost (s) and
    criterion); ``pose(done, total, record)`` after pose ``record`` was saved (``done`` now
    in the session); ``finished(result)`` with the run's ``AcquireResult`` when it ends
    without an error (also after a stop request)."""

    def planned(self, plan: Any) -> None:
        """The plan (before anything moves)."""

    def started(self, done: int, total: int, skipped: int = 0) -> None:
        """``done`` of ``total`` poses already in the session, ``skipped`` of them skipped."""

    def phase(self, i: int, name: str) -> None:
        """Pose ``i`` is now ``name``."""

    def predicted(self, prediction: Any, info: dict[str, Any]) -> None:
        """An adaptive run's prediction (``calib.prediction.Prediction``) and its decision."""

    def pose(self, done: int, total: int, record: PoseRecord) -> None:
        """Pose ``record`` was saved; ``done`` of ``total`` are now in the session."""

    def finished(self, result: Any) -> None:
        """The run ended; ``result`` is its ``AcquireResult``."""


class ProgressGroup(Progress):
    """Several Progress objects heard as one: every report goes to each, in order (e.g. the
    progress bar and a line per adaptive prediction)."""

    def __init__(self, *members: Progress) -> None:
        self.members = members

    def planned(self, plan: Any) -> None:
        for m in self.members:
            m.planned(plan)

    def started(self, done: int, total: int, skipped: int = 0) -> None:
        for m in self.members:
            m.started(done, total, skipped)

    def phase(self, i: int, name: str) -> None:
        for m in self.members:
            m.phase(i, name)

    def predicted(self, prediction: Any, info: dict[str, Any]) -> None:
        for m in self.members:
            m.predicted(prediction, info)

    def pose(self, done: int, total: int, record: PoseRecord) -> None:
        for m in self.members:
            m.pose(done, total, record)

    def finished(self, result: Any) -> None:
        for m in self.members:
            m.finished(result)
