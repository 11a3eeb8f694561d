"""Poses that excite the arm: a plan of joint configurations spread as far apart as the safety
envelope allows, for the kinematic estimate (docs/kinematics.md, "The joints plan"). Pure
numerics, no I/O; ``tmscal.acquisition`` runs it as the plan kind ``joints``.

An Eq. 14 plan (±100 mm, ±10° around P0; Wang et al. 2018) moves few joints far: the arm's
deviations show in the tracker only through the joints they multiply, so a plan that spreads
the joints identifies more of them. The plan:

* the joints ``q0`` (rad) at which the NOMINAL arm puts its flange at P0 (inverse kinematics
  from the joints the arm has: the configuration it is in), and the controller frame M
  (controller's frame ← the arm's DH base, 4×4 mm: identity when the controller reports in
  its base frame) from the arm's reported pose and joints;
* ``pool`` candidates drawn uniformly within ±``span_deg`` of q0 on every joint, clipped to
  the arm's joint limits (:func:`candidate_joints`, from ``numpy.random.default_rng(seed)``);
* each candidate's flange pose as the controller will be told it, M · base_from_flange(nominal,
  q) (4×4 mm); the candidates kept are those whose pose is within ``radius_mm`` and
  ``rotation_deg`` of P0 and inside the safety envelope (offset, rotation, the workspace box
  for the flange and the tool points: ``Envelope.violations``);
* n of them chosen by greedy farthest-point selection in joint space (Euclidean, rad),
  starting with the candidate farthest from q0 (:func:`farthest_points`): a deterministic
  choice of elementwise arithmetic only, so a resumed run re-derives it exactly, and the
  first k of an n-pose plan are the k-pose plan. The poses are visited in that order.

Everything the plan depends on — the arm, q0, M, seed, pool, span, the ranges and the
envelope (the config's) — is recorded in the session header or in the config, so a resumed
run draws the same plan again (``tmscal.acquisition.run``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import ConfigError
from ...geometry import angle_between
from .ik import inverse
from .model import Arm, base_from_flange

__all__ = ["JOINTS_SPAN_DEG", "JOINTS_POOL", "JointsPlan", "joint_window", "candidate_joints",
           "farthest_points", "start_joints", "joints_plan"]

#: default span (deg) of the candidates around q0 on every joint
JOINTS_SPAN_DEG = 30.0
#: default number of candidates drawn
JOINTS_POOL = 4000


@dataclass(frozen=True)
class JointsPlan:
    """A joints plan: the configurations ``q`` (n, dof) rad in visiting order, the flange poses
    ``poses`` (n, 4, 4) base_from_flange mm the controller is told (M · nominal forward
    kinematics), and how many of the ``pool`` candidates were ``inside``."""

    q: np.ndarray
    poses: np.ndarray
    inside: int
    pool: int


def joint_window(q0: np.ndarray, limits_rad: np.ndarray, span_rad: float | np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, int | None]:
    """The joint ranges (lo, hi) (dof,) rad within ±``span_rad`` (one value, or one per joint)
    of ``q0`` (rad) and inside ``limits_rad`` (dof, 2) rad, and the first joint (0-based) whose
    range is empty because ``q0`` lies outside its limits (None when every range holds).
    Candidates for the joints plan and for self-calibration are drawn in it."""
    q0 = np.asarray(q0, dtype=float)
    lim = np.asarray(limits_rad, dtype=float)
    lo = np.maximum(lim[:, 0], q0 - span_rad)
    hi = np.minimum(lim[:, 1], q0 + span_rad)
    bad = int(np.argmax(lo > hi)) if (lo > hi).any() else None
    return lo, hi, bad


def candidate_joints(q0: np.ndarray, limits_rad: np.ndarray, pool: int, span_deg: float,
                     rng: np.random.Generator) -> np.ndarray:
    """``pool`` joint configurations (pool, dof) rad uniform within ±``span_deg`` of ``q0``
    (rad) on every joint, inside ``limits_rad`` (dof, 2) rad (:func:`joint_window`)."""
    lo, hi, j = joint_window(q0, limits_rad, np.radians(float(span_deg)))
    if j is not None:
        lim = np.asarray(limits_rad, dtype=float)
        raise ConfigError(f"plan: joint {j + 1} is at {np.degrees(q0[j]):.1f}° at P0, outside "
                          f"the arm's joint limits [{np.degrees(lim[j, 0]):.1f}, "
                          f"{np.degrees(lim[j, 1]):.1f}]°")
    return lo + (hi - lo) * rng.uniform(0.0, 1.0, size=(int(pool), len(lo)))


def farthest_points(q: np.ndarray, k: int, start: np.ndarray) -> np.ndarray:
    """Indices of ``k`` rows of ``q`` (m, dof) chosen greedily, each the one farthest
    (Euclidean) from ``start`` (dof,) and the rows chosen before it; stops early when every
    row left coincides with one chosen. Elementwise arithmetic only (no BLAS), so the choice
    is the same on every machine; the first j of k indices are the choice of j."""
    q = np.asarray(q, dtype=float)
    d = np.sqrt(((q - np.asarray(start, dtype=float)) ** 2).sum(axis=1))
    out: list[int] = []
    while len(out) < min(k, len(q)):
        j = int(np.argmax(d))
        if out and d[j] == 0:
            break
        out.append(j)
        d = np.minimum(d, np.sqrt(((q - q[j]) ** 2).sum(axis=1)))
    return np.array(out, dtype=int)


def start_joints(arm: Arm, p0: np.ndarray, q_now: np.ndarray, A_now: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(q0 rad, M 4×4 mm): the controller frame M = A_now · base_from_flange(arm, q_now)⁻¹
    from the arm's reported flange ``A_now`` (4×4 mm) at its joints ``q_now`` (rad), and the
    joints q0 at which the nominal ``arm`` puts its flange at ``p0`` (4×4 mm, the controller's
    frame), by inverse kinematics from q_now. ConfigError when P0 is out of the arm's reach."""
    q_now = np.asarray(q_now, dtype=float)
    if q_now.shape != (arm.n_joints,) or not np.isfinite(q_now).all():
        raise ConfigError(f"plan: the robot reports {q_now.size} joint angles; the "
                          f"{arm.name} arm has {arm.n_joints}: is plan.arm the robot's arm?")
    M = np.asarray(A_now, dtype=float) @ np.linalg.inv(base_from_flange(arm, q_now))
    q0 = inverse(arm, np.linalg.inv(M) @ np.asarray(p0, dtype=float), [q_now])
    if q0 is None:
        raise ConfigError(f"plan: the {arm.name} arm's nominal kinematics cannot reach P0 "
                          f"{np.round(np.asarray(p0)[:3, 3], 1).tolist()} mm from its "
                          "present joints: is plan.arm the robot's arm?")
    return q0, M


def joints_plan(arm: Arm, q0: np.ndarray, frame: np.ndarray, p0: np.ndarray, n: int, seed: int,
                pool: int, span_deg: float, radius_mm: float, rotation_deg: float,
                envelope: Any = None) -> JointsPlan:
    """The joints plan (module docstring) of ``n`` configurations of the nominal ``arm``
    around ``q0`` (rad), its poses in the controller frame ``frame`` (M, 4×4 mm) within
    ``radius_mm`` and ``rotation_deg`` of ``p0`` (base_from_flange 4×4 mm) and inside
    ``envelope`` (a ``tmscal.safety.Envelope`` or None). ConfigError naming the keys to change
    when fewer than ``n`` candidates are inside."""
    p0 = np.asarray(p0, dtype=float)
    frame = np.asarray(frame, dtype=float)
    cand = candidate_joints(q0, arm.joint_limits_rad, pool, span_deg,
                            np.random.default_rng(seed))
    poses = frame @ base_from_flange(arm, cand)
    off = np.sqrt(((poses[:, :3, 3] - p0[:3, 3]) ** 2).sum(axis=1))
    rot = np.degrees(angle_between(p0, poses))
    keep = (off <= radius_mm) & (rot <= rotation_deg)
    if envelope is not None:
        keep &= np.array([not envelope.violations(P) if k else False
                          for P, k in zip(poses, keep, strict=True)], dtype=bool)
    inside = int(keep.sum())
    if inside < n:
        raise ConfigError(
            f"plan: only {inside} of {pool} joint configurations within ±{span_deg:g}° of the "
            f"{arm.name} arm's joints at P0 put the flange within plan.radius_mm "
            f"{radius_mm:g} and plan.rotation_deg {rotation_deg:g} of P0 and inside the safety "
            f"envelope; {n} are needed: raise plan.pool, change plan.span_deg, widen the "
            "ranges or the safety envelope, or ask for fewer poses")
    cand, poses = cand[keep], poses[keep]
    idx = farthest_points(cand, n, q0)
    if len(idx) < n:
        raise ConfigError(f"plan: only {len(idx)} distinct joint configurations inside; {n} "
                          "are needed")
    return JointsPlan(q=cand[idx], poses=poses[idx], inside=inside, pool=int(pool))
