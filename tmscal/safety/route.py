"""One move as the robot will be sent it: checked along its whole path, split through P0 when the
straight path would leave the envelope, and timed so that every tool point keeps under the caps.

:func:`plan_move` is what ``Robot.move_to`` runs before it sends anything:

1. The robot's pose now (the start) must be inside the envelope.
2. The path the controller takes from the start to the target (the driver's
   :class:`MotionLaw`: :mod:`tmscal.safety.paths`) must stay inside: the flange origin and
   every tool point in the box, the flange within the offset and rotation limits of P0.
3. The split rule, when it does not: translate to the centre (P0's position, else the box's
   centre) keeping the start orientation, turn there to the target orientation, translate to
   the target keeping it. If that leaves the envelope too and there is a P0, the turn at the
   centre goes through P0's own orientation (turn back to it, then on to the target's: each
   turn moves monotonically away from or towards P0's orientation, so the rotation limit
   holds on the way). A controller that times only the translation (a DENSO ``MOVE L``:
   :class:`~.laws.SharedProfile` with K = 0) cannot time a turn on the spot once tool points
   are carried, so for it the turn is made while translating instead: to the centre turning
   to the target orientation, then to the target keeping it (or the other way round: to the
   centre keeping the start orientation, then to the target turning). Each leg (and every
   waypoint) is checked the same way; a leg of no motion is dropped. If a leg still leaves
   the envelope, the move is refused, naming the move (from → to, mm), the point (flange
   origin or tool point i), where, and which wall.
4. Each leg's speed and acceleration are lowered for the fastest point (:mod:`.laws`).

Nothing is sent by this module; a refusal is a ``SafetyError`` ending "Nothing was moved."
Poses are base_from_flange 4×4 mm; speeds mm/s, accelerations mm/s².
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SafetyError
from ..geometry import angle_between, invert, rotvec_from_matrix
from .envelope import Envelope
from .laws import NEGLIGIBLE_MM, AxisProfile, SharedProfile, Timing, scale
from .paths import AxisPath, LinearPath, Violation, check_path

__all__ = ["MotionLaw", "Leg", "Route", "plan_move", "split_waypoints", "DEFAULT_LAW"]


@dataclass(frozen=True)
class MotionLaw:
    """How a controller executes one Cartesian move: the ``path`` its frame takes
    (:class:`~.paths.LinearPath` or :class:`~.paths.AxisPath`) and the ``timing`` law that
    sets its speed (:class:`~.laws.SharedProfile` or :class:`~.laws.AxisProfile`). Each robot
    driver declares its own (``Robot.motion_law``)."""

    path: LinearPath | AxisPath = field(default_factory=LinearPath)
    timing: Timing = field(default_factory=lambda: SharedProfile(0.0))


#: a driver that declares nothing: a linear move of the flange whose rotation is timed only by
#: its translation (the most cautious of the laws here)
DEFAULT_LAW = MotionLaw()


@dataclass(frozen=True)
class Leg:
    """One motion to send: from flange ``start`` to flange ``target`` (4×4 mm) at
    ``speed_mm_s`` and ``accel_mm_s2``."""

    start: np.ndarray
    target: np.ndarray
    speed_mm_s: float
    accel_mm_s2: float


@dataclass(frozen=True)
class Route:
    """The legs of one move, in order; ``split`` when the straight path was replaced by the
    route through P0 (``why``: the limit the straight path broke)."""

    legs: tuple[Leg, ...]
    split: bool = False
    why: str = ""


def _fmt(pose: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.1f}" for x in np.asarray(pose)[:3, 3]) + ")"


def split_waypoints(env: Envelope, start: np.ndarray, target: np.ndarray,
                    via_p0: bool = False) -> list[np.ndarray] | None:
    """The split route's poses [start, W1, (P0,) W2, target] (legs of no motion dropped): W1
    is the start orientation at the centre (P0's position, else the box's centre), W2 the
    target orientation there; ``via_p0`` turns through P0's own orientation in between (two
    turns, each moving monotonically away from or towards P0's orientation). None when the
    envelope has no centre (or, with ``via_p0``, no P0)."""
    c = _centre(env)
    if c is None or (via_p0 and env.center is None):
        return None
    w1, w2 = np.array(start, dtype=np.float64), np.array(target, dtype=np.float64)
    w1[:3, 3] = c
    w2[:3, 3] = c
    via = [w1, np.array(env.center, dtype=np.float64), w2] if via_p0 else [w1, w2]
    out = [np.asarray(start, dtype=np.float64)]
    for p in (*via, np.asarray(target, dtype=np.float64)):
        if not _same(out[-1], p):
            out.append(p)
    return out


def _centre(env: Envelope) -> np.ndarray | None:
    """Where a split route turns (mm, base frame): P0's position, else the box's centre, else
    None."""
    if env.center is not None:
        return np.asarray(env.center, dtype=np.float64)[:3, 3]
    if env.has_box:
        return 0.5 * (np.asarray(env.box_min_mm, dtype=np.float64)
                      + np.asarray(env.box_max_mm, dtype=np.float64))
    return None


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.linalg.norm(a[:3, 3] - b[:3, 3]) <= 1e-9
                and float(angle_between(a, b)) <= 1e-12)


def _leg_geometry(law: MotionLaw, env: Envelope, start: np.ndarray, target: np.ndarray
                  ) -> tuple[float, float, float]:
    """(d mm, θ rad, ρ mm) of one leg in the controller's frame: its translation, its turn and
    the largest distance of a checked point from the rotation axis (per-axis law: from the
    frame's origin)."""
    phi = np.asarray(law.path.flange_from_frame, dtype=np.float64)
    A, B = start @ phi, target @ phi
    d = float(np.linalg.norm(B[:3, 3] - A[:3, 3]))
    rv = rotvec_from_matrix(A[:3, :3].T @ B[:3, :3])
    theta = float(np.linalg.norm(rv))
    pts, _ = env.checked_points()
    inv = invert(phi)
    q = pts @ inv[:3, :3].T + inv[:3, 3]                 # the points in the frame's axes
    if isinstance(law.timing, AxisProfile) or theta == 0:
        rho = np.linalg.norm(q, axis=1)
    else:
        n = rv / theta
        rho = np.linalg.norm(q - np.outer(q @ n, n), axis=1)
    return d, theta, float(rho.max(initial=0.0))


def plan_move(env: Envelope, start: np.ndarray, target: np.ndarray, law: MotionLaw,
              speed_mm_s: float, accel_mm_s2: float, what: str = "move") -> Route:
    """The legs to send for a move of the flange from ``start`` (where the robot is now) to
    ``target`` (both base_from_flange 4×4 mm) at most at ``speed_mm_s`` and ``accel_mm_s2``
    (module docstring). ``SafetyError`` naming the move, the point and the wall when neither
    the straight path nor the split route stays inside, or when the start is outside."""
    start = np.asarray(start, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    move = f"{what} {_fmt(start)} → {_fmt(target)} mm"
    here = env.violations(start)
    if here:
        raise SafetyError(f"{move} refused: the robot is outside the safety envelope now "
                          f"({'; '.join(here)}); bring it inside first. Nothing was moved.")
    bad = env.violations(target)
    if bad:
        raise SafetyError(f"{move} refused: the target is outside the safety envelope "
                          f"({'; '.join(bad)}). Nothing was moved.")
    poses = [start, target]
    split, why = False, ""
    straight = check_path(env, start, target, law.path)
    if straight is not None:
        poses, why = _split(env, start, target, law, move, straight), str(straight)
        split = True
    legs = []
    for i, (a, b) in enumerate(zip(poses[:-1], poses[1:], strict=True)):
        d, theta, rho = _leg_geometry(law, env, a, b)
        name = move if len(poses) == 2 else f"{move} (leg {i + 1} of {len(poses) - 1})"
        v, acc = scale(law.timing, d, theta, rho, float(speed_mm_s), float(accel_mm_s2),
                       env.max_speed_mm_s, env.max_accel_mm_s2, name)
        legs.append(Leg(a, b, v, acc))
    return Route(tuple(legs), split, why)


def _split(env: Envelope, start: np.ndarray, target: np.ndarray, law: MotionLaw, move: str,
           straight: Violation) -> list[np.ndarray]:
    """The split route's poses, each leg checked: turning at the centre straight from the
    start's orientation to the target's, else (with a P0) through P0's orientation;
    ``SafetyError`` naming the straight path's failure and each route's when none stays
    inside."""
    why: list[str] = []
    tried: list[list[np.ndarray]] = []
    candidates = [(split_waypoints(env, start, target, via_p0),
                   " turning through P0's orientation" if via_p0 else "")
                  for via_p0 in (False, True)]
    if _turns_untimed(law, env):
        timed = [c for c in candidates if c[0] is not None and not _turns_on_the_spot(c[0])]
        if len(timed) < sum(c[0] is not None for c in candidates):
            why.append(f"{law.timing.name} cannot time the split route's turn at the centre "
                       "(it times only the translation; docs/safety.md)")
        candidates = timed + [
            (_turning_waypoints(env, start, target, early),
             " turning on the way in" if early else " turning on the way out")
            for early in (True, False)]
    for poses, how in candidates:
        if poses is None or any(len(p) == len(poses) and all(_same(a, b) for a, b in
                                                               zip(p, poses, strict=True))
                                for p in tried):
            continue
        tried.append(poses)
        bad = _route_violation(env, poses, law, how)
        if bad is None:
            return poses
        why.append(bad)
    if not why:
        why.append("the envelope has no P0 or box centre to split the move through")
    raise SafetyError(f"{move} refused: {straight}; {'; '.join(why)}. Nothing was moved.")


def _turns_untimed(law: MotionLaw, env: Envelope) -> bool:
    """True when ``law`` times only the translation (SharedProfile, K = 0) and the envelope
    carries tool points, so that a turn on the spot cannot be sent (:mod:`.laws`)."""
    pts, _ = env.checked_points()
    far = float(np.linalg.norm(pts, axis=1).max(initial=0.0)) if len(pts) else 0.0
    return (isinstance(law.timing, SharedProfile) and law.timing.rotation_mm_per_rad <= 0
            and far > NEGLIGIBLE_MM)


def _turning_waypoints(env: Envelope, start: np.ndarray, target: np.ndarray, early: bool
                       ) -> list[np.ndarray] | None:
    """A split route without a turn on the spot: [start, W, target] with W at the centre (P0's
    position, else the box's centre) in the target's orientation (``early``: turn on the way
    to the centre) or the start's (turn on the way out). None without a centre."""
    c = _centre(env)
    if c is None:
        return None
    w = np.array(target if early else start, dtype=np.float64)
    w[:3, 3] = c
    out = [np.asarray(start, dtype=np.float64)]
    for p in (w, np.asarray(target, dtype=np.float64)):
        if not _same(out[-1], p):
            out.append(p)
    return out


def _route_violation(env: Envelope, poses: list[np.ndarray], law: MotionLaw, how: str
                     ) -> str | None:
    """Why the split route ``poses`` (``how`` it turns, for the message) leaves the envelope
    (its waypoints, then its legs), or None when it stays inside."""
    centre = _fmt(poses[1]) if len(poses) > 2 else "P0"
    route = f"the split route through {centre} mm{how}"
    for w in poses[1:-1]:
        bad = env.violations(w)
        if bad:
            return f"{route} does not help: a waypoint there is outside ({'; '.join(bad)})"
    for i, (a, b) in enumerate(zip(poses[:-1], poses[1:], strict=True)):
        v = check_path(env, a, b, law.path)
        if v is not None:
            return f"{route} does not help: its leg {i + 1} ({_leg_name(a, b, i)}) {v}"
    return None


def _turns_on_the_spot(poses: list[np.ndarray]) -> bool:
    """Whether a split route has a leg that turns without translating."""
    return any(np.linalg.norm(a[:3, 3] - b[:3, 3]) <= 1e-9 and not _same(a, b)
               for a, b in zip(poses[:-1], poses[1:], strict=True))


def _leg_name(a: np.ndarray, b: np.ndarray, i: int) -> str:
    """What leg a → b of a split route does: turn at the centre, or translate to / from it
    (turning on the way, for a controller that cannot turn on the spot)."""
    if np.linalg.norm(a[:3, 3] - b[:3, 3]) <= 1e-9:
        return "turn at the centre"
    name = "translate to the centre" if i == 0 else "translate from the centre"
    return name + (", turning" if float(angle_between(a, b)) > 1e-12 else "")
