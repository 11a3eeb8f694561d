"""What can move on a rig after its calibration, applied to the sim rig's truth: the tracker,
the marker on the coil, the coil (with its marker) re-seated on the flange, the coil's centre.

The mock rig applies ``mock.changes`` to its truth when it is built and ``mock.events`` while
it runs (docs/configs.md, ``mock``; docs/devices.md, "The mock rig: changes and events"), so
it stands differently from the truth a calibration was solved on. Each change is a
translation ``mm`` (3,) and a rotation vector ``deg`` (3,: axis × angle in degrees); ‖mm‖ is
the displacement and ‖deg‖ the rotation angle it makes (for ‖deg‖ ≤ 180°). With R = R(deg)
and T(t) the pure translation by t (4×4 mm; X = flange_from_marker, Y = flange_from_probe,
Z = base_from_tracker):

* ``tracker``: Z' = [R·R_Z, t_Z + mm]: the tracker turned about its own origin by ``deg``
  (base-frame axes) and moved by ``mm`` in the base frame;
* ``marker``: X' = X·[R, mm]: the marker moved on the coil by ``mm`` in its own frame and
  turned about its own origin;
* ``coil_centre``: Y' = Y·[R, mm] (another coil, or the probe re-placed);
* ``coil``: the coil and its marker re-seated on the flange, one flange-frame rigid motion
  Δ = T(t_Y + mm)·R·T(−t_Y) of both, X' = Δ·X and Y' = Δ·Y: the coil centre moves by ``mm``
  (flange axes), ‖t(Y') − t(Y)‖ = ‖mm‖, and the assembly turns by ``deg`` (flange axes)
  about the coil centre; on a rig without a probe (Y None) about the marker's origin t_X.

Several changes at once are applied in the order of ``MOVES`` (tracker, marker, coil,
coil_centre), whatever order they are given in; only ``coil`` and ``coil_centre`` do not
commute (a coil re-seated about its centre, then the centre moved).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..geometry import make_pose, matrix_from_rotvec
from .truth import Truth

__all__ = ["MOVES", "Change", "Event", "changed", "apply_changes"]

#: what a change moves, in the order several changes are applied
MOVES = ("tracker", "marker", "coil", "coil_centre")


def _vec(value: Sequence[float], name: str) -> np.ndarray:
    """``value`` as three finite floats (3,), else ValueError naming ``name``."""
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: expected three finite numbers, got {value!r}")
    return v


def changed(truth: Truth, move: str, mm: Sequence[float] = (0.0, 0.0, 0.0),
            deg: Sequence[float] = (0.0, 0.0, 0.0)) -> Truth:
    """``truth`` after one change (module docstring): ``move`` one of ``MOVES``, ``mm`` the
    translation (mm), ``deg`` the rotation vector (degrees), both (3,). Returns a new Truth
    (its arm kept); ValueError for an unknown move, a value that is not three finite numbers,
    or ``coil_centre`` on a rig without a probe."""
    if move not in MOVES:
        raise ValueError(f"move: expected one of {', '.join(MOVES)}, got {move!r}")
    t = _vec(mm, "mm")
    R = matrix_from_rotvec(np.radians(_vec(deg, "deg")))
    if move == "tracker":
        Z = make_pose(R @ truth.Z[:3, :3], truth.Z[:3, 3] + t)
        return replace(truth, Z=Z)
    if move == "marker":
        return replace(truth, X=truth.X @ make_pose(R, t))
    if move == "coil_centre":
        if truth.Y is None:
            raise ValueError("coil_centre: the rig has no probe (no Y) to move")
        return replace(truth, Y=truth.Y @ make_pose(R, t))
    c = (truth.Y if truth.Y is not None else truth.X)[:3, 3]
    delta = make_pose(None, c + t) @ make_pose(R) @ make_pose(None, -c)
    return replace(truth, X=delta @ truth.X,
                   Y=None if truth.Y is None else delta @ truth.Y)


@dataclass(frozen=True)
class Change:
    """One change of the rig (module docstring): ``move`` one of ``MOVES``, ``mm`` the
    translation (mm) and ``deg`` the rotation vector (degrees), three finite numbers each."""

    move: str
    mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.move not in MOVES:
            raise ValueError(f"move: expected one of {', '.join(MOVES)}, got {self.move!r}")
        for name in ("mm", "deg"):
            v = _vec(getattr(self, name), name)
            object.__setattr__(self, name, (float(v[0]), float(v[1]), float(v[2])))

    def apply(self, truth: Truth) -> Truth:
        """``changed(truth, move, mm, deg)``."""
        return changed(truth, self.move, self.mm, self.deg)


@dataclass(frozen=True)
class Event:
    """A change (``Change``) that happens ``at_s`` seconds (≥ 0) of the rig's time after the
    rig's clock started (``SimRig.now``; ``SimRig.use_clock``)."""

    at_s: float
    change: Change

    def __post_init__(self) -> None:
        if (isinstance(self.at_s, bool) or not isinstance(self.at_s, int | float)
                or not (math.isfinite(self.at_s) and self.at_s >= 0)):
            raise ValueError(f"at_s: expected a finite number ≥ 0, got {self.at_s!r}")
        object.__setattr__(self, "at_s", float(self.at_s))


def apply_changes(truth: Truth, changes: Iterable[Change]) -> Truth:
    """``truth`` after several changes, at most one per move, applied in the order of
    ``MOVES`` whatever their order here (ValueError for a move given twice)."""
    items = list(changes)
    moves = [c.move for c in items]
    twice = sorted({m for m in moves if moves.count(m) > 1})
    if twice:
        raise ValueError(f"{twice[0]}: given more than once")
    for c in sorted(items, key=lambda c: MOVES.index(c.move)):
        truth = c.apply(truth)
    return truth
