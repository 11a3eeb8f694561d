"""Where a move goes between its two ends, and whether ALL of it stays inside the envelope.

A controller does not jump from one pose to the next: it moves its own frame along a path. This
module knows three paths and checks the flange origin and every tool point (the envelope's
``checked_points``) along each, against the workspace box, and the flange against the offset
and rotation limits around P0:

* :class:`LinearPath` — a linear move (UR ``moveL``, DENSO ``MOVE L``): the controller's frame
  (``flange_from_frame``: the UR's TCP, the flange on a DENSO) moves on the straight line and
  turns on the rotation geodesic (slerp), both driven by ONE path share f ∈ [0, 1]
  (docs/devices.md, "Motion"). :func:`check_linear` — exact up to LIMIT_TOL: see below.
* :class:`AxisPath` — franky's Cartesian motion (Franka): Ruckig plans each of x, y, z (in the
  START end-effector frame) and the three components of the rotation vector relative to the
  start on its own profile, all ending together (time synchronisation, not phase
  synchronisation), so the path is NOT straight. Each coordinate moves monotonically from its
  start to its target value, so every pose of the move lies in the "hull": translation in the
  box spanned by 0 and Δu, rotation vector in the box spanned by 0 and Δr. :func:`check_axis`
  checks that whole hull (conservative).
* a joint-space move, given a forward-kinematics function: :func:`check_joint_path`.

The sampling bound of a linear move. A point q of the controller's frame (at distance ρ from the
rotation axis through the frame's origin) follows p(f) = a + f·Δ + R_A·exp(f·θ·n)·q: a straight
line plus a circular arc of radius ρ, both uniform in f. Between two samples f_j, f_{j+1} the
frame turns by Δθ = θ·(f_{j+1} − f_j), and every point of p on that piece lies within
δ = ρ·Δθ²/8 of the chord p(f_j)p(f_{j+1}) (the interpolation error of a curve whose second
derivative is at most ρ·Δθ² in the piece's own parameter: |error| ≤ max|p''|/8). The box and
the offset ball are convex, so if both samples lie in the box (ball) SHRUNK by δ, the chord does
too, and the piece lies in the box (ball). :func:`check_linear` samples every move finely
enough that δ ≤ ``SAG_MM`` to start with, checks each piece against the shrunk box, and halves
the pieces that fail only by the margin (δ falls fourfold each time) until they pass or a sample
is genuinely outside. The rotation from P0 along the geodesic is exact: the trace of
P0ᵀ·R(f) is a sinusoid in f·θ, minimised in closed form.

The hull of a franky move is checked by branch and bound over the rotation-vector box
(:func:`certify`): a point's place moves by at most |q|·|Δr| when the rotation vector moves by
Δr (the exponential map of SO(3) does not lengthen paths: non-negative curvature), and the
translation part's extremes are at the box's corners.

A joint-space move q(s) = q0 + s·(q1 − q0): a point whose distance from joint i's axis is at
most ``reach_i`` moves by at most Σ|Δq_i|·reach_i per unit of s (the Lipschitz bound), the
flange turns by at most Σ|Δq_i|; :func:`check_joint_path` certifies the sampled move with
these bounds (branch and bound in s).

Units: mm, radians inside (degrees in messages); poses are base_from_flange 4×4 mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..geometry import angle_between, invert, matrix_from_rotvec, rotvec_from_matrix
from .envelope import LIMIT_TOL, Envelope

__all__ = ["LinearPath", "AxisPath", "Violation", "SAG_MM", "check_linear", "check_axis",
           "check_joint_path", "check_path", "certify", "linear_flange_poses", "linear_frame"]

#: the largest chord sag (mm) of the first sampling of a linear move; failing pieces are
#: refined further (see the module docstring)
SAG_MM = 0.05
#: the most halvings of one piece of a linear move before it counts as "cannot be shown
#: inside" (δ falls 4¹⁰ ≈ 10⁶-fold)
MAX_REFINE = 10
#: a branch-and-bound cell whose upper bound is within this of a limit (mm, or rad for the
#: rotation) counts as inside; cells over it are split
CERTIFY_TOL = 1e-4
#: the most cells a branch and bound evaluates before it gives up (and the move is refused)
CERTIFY_BUDGET = 400_000


def _identity() -> np.ndarray:
    return np.eye(4)


@dataclass(frozen=True, eq=False)
class LinearPath:
    """A linear move: the controller's frame, ``flange_from_frame`` (4×4 mm; the UR's TCP
    offset, identity for the flange), moves on the straight line and the rotation geodesic
    with one path share (module docstring)."""

    flange_from_frame: np.ndarray = field(default_factory=_identity)


@dataclass(frozen=True, eq=False)
class AxisPath:
    """franky's Cartesian motion: each translation axis of the START frame and each component
    of the rotation vector from it moves monotonically on its own profile (module docstring);
    ``flange_from_frame`` (4×4 mm) is the end effector the controller moves (F_T_EE)."""

    flange_from_frame: np.ndarray = field(default_factory=_identity)


@dataclass(frozen=True)
class Violation:
    """Where a move breaks a limit: ``what`` (the flange origin, tool point i, the flange's
    rotation), ``where_mm`` (the point in the base frame, mm; None for a rotation), ``share``
    (0…1 of the way, None when the path model gives no share), ``limit`` (the wall or limit,
    e.g. "the workspace box's x-min wall (300.0 mm)") and ``excess`` beyond it (mm, or
    degrees for a rotation). ``certain`` is False when the move came within the sampling
    margin of the limit and could not be shown inside."""

    what: str
    where_mm: np.ndarray | None
    share: float | None
    limit: str
    excess: float
    unit: str = "mm"
    certain: bool = True

    def __str__(self) -> str:
        at = "" if self.where_mm is None else \
            f" at {np.round(self.where_mm, 1).tolist()} mm"
        way = "" if self.share is None else f" {self.share:.0%} of the way"
        unit = self.unit if self.unit == "°" else f" {self.unit}"
        if self.certain:
            return f"{self.what} would go {self.excess:.1f}{unit} beyond {self.limit}{way}{at}"
        return (f"{self.what} cannot be shown to stay inside {self.limit}{way}{at} (within "
                f"{max(self.excess, 0.0):.2g}{unit} of it)")


# --- the constraints of one envelope, on many flange poses ---------------------------------------

class _Constraints:
    """The envelope's limits as columns g ≤ 0 (mm; rad for the rotation) over flange poses.

    Box columns come per checked point (flange origin first, then the tool points) in the order
    x-min, x-max, y-min, y-max, z-min, z-max; then the offset from P0 (flange origin); then
    the rotation from P0. ``kinds`` says which: "box", "offset", "rotation"; ``point`` which
    checked point a column belongs to (−1 for the rotation)."""

    def __init__(self, env: Envelope) -> None:
        self.env = env
        self.points, self.point_names = env.checked_points()      # flange frame
        self.kinds: list[str] = []
        self.point: list[int] = []
        self.labels: list[str] = []
        if env.has_box:
            lo, hi = np.asarray(env.box_min_mm), np.asarray(env.box_max_mm)
            for i in range(len(self.points)):
                for ax, name in enumerate("xyz"):
                    for side, v in (("min", lo[ax]), ("max", hi[ax])):
                        self.kinds.append("box")
                        self.point.append(i)
                        self.labels.append(f"the workspace box's {name}-{side} wall "
                                           f"({v:.1f} mm)")
        self.offset = env.center is not None and env.max_offset_mm is not None
        if self.offset:
            self.kinds.append("offset")
            self.point.append(0)
            self.labels.append(f"max_offset_mm {env.max_offset_mm:g} from P0")
        self.rotation = env.center is not None and env.max_rotation_deg is not None
        if self.rotation:
            self.kinds.append("rotation")
            self.point.append(-1)
            self.labels.append(f"max_rotation_deg {env.max_rotation_deg:g} from P0")
        self.kind_arr = np.array(self.kinds)
        self.point_arr = np.array(self.point, dtype=int)

    def __len__(self) -> int:
        return len(self.kinds)

    def box_values(self, pts: np.ndarray) -> np.ndarray:
        """(n, k·6) box columns from base-frame points (n, k, 3) mm."""
        lo, hi = np.asarray(self.env.box_min_mm), np.asarray(self.env.box_max_mm)
        g = np.stack([lo - pts, pts - hi], axis=-1)       # (n, k, 3, 2): min, max per axis
        return g.reshape(len(pts), -1)

    def values(self, poses: np.ndarray, rotation: bool = True) -> np.ndarray:
        """(n, C) column values of flange poses (n, 4, 4) mm (without the rotation column
        when ``rotation`` is False)."""
        poses = np.asarray(poses, dtype=np.float64)
        cols = []
        if self.env.has_box:
            pts = np.einsum("nij,kj->nki", poses[:, :3, :3], self.points) + poses[:, None, :3, 3]
            cols.append(self.box_values(pts))
        env = self.env
        if self.offset:
            assert env.center is not None and env.max_offset_mm is not None
            d = np.linalg.norm(poses[:, :3, 3] - env.center[:3, 3], axis=1)
            cols.append((d - env.max_offset_mm)[:, None])
        if self.rotation and rotation:
            assert env.center is not None and env.max_rotation_deg is not None
            ang = angle_between(env.center, poses)
            cols.append((ang - math.radians(env.max_rotation_deg))[:, None])
        return np.concatenate(cols, axis=1) if cols else np.zeros((len(poses), 0))

    def violation(self, col: int, excess: float, pose: np.ndarray | None,
                  share: float | None, certain: bool = True) -> Violation:
        """The Violation of column ``col`` by ``excess`` (mm or rad) at flange ``pose``."""
        kind, i = self.kinds[col], self.point[col]
        if kind == "rotation":
            return Violation("the flange's rotation", None, share, self.labels[col],
                             math.degrees(excess), "°", certain)
        where = None if pose is None else pose[:3, :3] @ self.points[i] + pose[:3, 3]
        return Violation(self.point_names[i], where, share, self.labels[col], excess, "mm",
                         certain)


# --- linear moves ------------------------------------------------------------------------------

@dataclass(frozen=True)
class _LinearGeometry:
    """A linear move in the controller's frame: start frame pose A (rotation ``RA``, origin
    ``a``), translation ``delta`` (mm), rotation ``theta`` (rad) about unit axis ``n`` (in A's
    axes), and ``frame_from_flange`` to carry flange-frame points into the frame."""

    a: np.ndarray
    delta: np.ndarray
    RA: np.ndarray
    theta: float
    n: np.ndarray
    flange_from_frame: np.ndarray
    frame_from_flange: np.ndarray


def linear_frame(start: np.ndarray, target: np.ndarray,
                 flange_from_frame: np.ndarray | None = None) -> _LinearGeometry:
    """The geometry of a linear move from flange ``start`` to flange ``target`` (4×4 mm) of a
    controller that interpolates ``flange_from_frame`` (identity: the flange)."""
    phi = np.eye(4) if flange_from_frame is None else np.asarray(flange_from_frame, float)
    A, B = np.asarray(start, float) @ phi, np.asarray(target, float) @ phi
    rv = rotvec_from_matrix(A[:3, :3].T @ B[:3, :3])
    theta = float(np.linalg.norm(rv))
    n = rv / theta if theta > 0 else np.zeros(3)
    return _LinearGeometry(A[:3, 3].copy(), B[:3, 3] - A[:3, 3], A[:3, :3].copy(), theta, n,
                           phi, invert(phi))


def linear_flange_poses(start: np.ndarray, target: np.ndarray, shares: Sequence[float] | np.ndarray,
                        flange_from_frame: np.ndarray | None = None) -> np.ndarray:
    """The flange poses (n, 4, 4) mm at path shares ``shares`` of a linear move of the frame
    ``flange_from_frame`` from flange ``start`` to flange ``target``."""
    geo = linear_frame(start, target, flange_from_frame)
    return _frame_poses(geo, np.asarray(shares, dtype=np.float64)) @ geo.frame_from_flange


def _frame_poses(geo: _LinearGeometry, f: np.ndarray) -> np.ndarray:
    """The frame's poses (n, 4, 4) at shares f: R_A·exp(f·θ·n) and a + f·Δ."""
    E = matrix_from_rotvec((f * geo.theta)[:, None] * np.asarray(geo.n)[None])
    out = np.zeros((len(f), 4, 4))
    out[:, 3, 3] = 1.0
    out[:, :3, :3] = geo.RA @ E
    out[:, :3, 3] = geo.a + f[:, None] * geo.delta
    return out


def _axis_distance(q: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Distances (k,) of points q (k, 3) from the axis through the origin along unit n."""
    return np.linalg.norm(q - np.outer(q @ n, n), axis=1)


def _max_rotation_linear(env: Envelope, geo: _LinearGeometry) -> tuple[float, float]:
    """(largest rotation of the flange from P0 along the move, rad; the share where): exact.
    trace(Cᵀ·R_A·exp(u·n)·Φᵀ) = trace(N·exp(u·n)), N = Φᵀ·Cᵀ·R_A, is c + s·sin u − k·cos u
    for u = f·θ in [0, θ]; its minimum is at an end or where the derivative vanishes."""
    assert env.center is not None
    N = geo.flange_from_frame[:3, :3].T @ env.center[:3, :3].T @ geo.RA
    K = np.array([[0, -geo.n[2], geo.n[1]], [geo.n[2], 0, -geo.n[0]],
                  [-geo.n[1], geo.n[0], 0]])
    t0, t1, t2 = float(np.trace(N)), float(np.trace(N @ K)), float(np.trace(N @ K @ K))

    def trace(u: float) -> float:
        return t0 + t1 * math.sin(u) + t2 * (1.0 - math.cos(u))

    us = [0.0, geo.theta]
    if geo.theta > 0:
        uc = math.atan2(-t1, t2)            # d/du = t1 cos u + t2 sin u = 0
        for k in range(-2, 3):
            u = uc + k * math.pi
            if 0.0 < u < geo.theta:
                us.append(u)
    u_min = min(us, key=trace)
    c = max(-1.0, min(1.0, (trace(u_min) - 1.0) / 2.0))
    return math.acos(c), (u_min / geo.theta if geo.theta > 0 else 0.0)


def check_linear(env: Envelope, start: np.ndarray, target: np.ndarray,
                 path: LinearPath | None = None) -> Violation | None:
    """The first limit a linear move from flange ``start`` to flange ``target`` (4×4 mm)
    breaks anywhere along the way (the worst excursion of that limit), or None when all of it
    stays inside the envelope. See the module docstring for the bound that makes the sampled
    check exact."""
    geo = linear_frame(start, target, None if path is None else path.flange_from_frame)
    cons = _Constraints(env)
    if cons.rotation:
        assert env.max_rotation_deg is not None
        worst, share = _max_rotation_linear(env, geo)
        excess = worst - math.radians(env.max_rotation_deg)
        if excess > math.radians(LIMIT_TOL):
            col = len(cons) - 1
            pose = linear_flange_poses(start, target, [share], geo.flange_from_frame)[0]
            return cons.violation(col, excess, pose, share)
    cols = np.flatnonzero(cons.kind_arr != "rotation")
    if len(cols) == 0:
        return None
    q_frame = (cons.points @ geo.frame_from_flange[:3, :3].T) + geo.frame_from_flange[:3, 3]
    rho = _axis_distance(q_frame, geo.n) if geo.theta > 0 else np.zeros(len(q_frame))
    weight = rho[cons.point_arr[cols]] * geo.theta ** 2 / 8.0      # δ = weight · Δf²

    def g(f: np.ndarray) -> np.ndarray:
        poses = _frame_poses(geo, f) @ geo.frame_from_flange
        return cons.values(poses, rotation=False)

    n0 = max(8, math.ceil(geo.theta * math.sqrt(float(rho.max(initial=0.0)) / (8 * SAG_MM))))
    f = np.linspace(0.0, 1.0, n0 + 1)
    G = g(f)
    fa, fb, Ga, Gb = f[:-1], f[1:], G[:-1], G[1:]
    for _ in range(MAX_REFINE + 1):
        if (G > LIMIT_TOL).any():
            return _worst_linear(cons, cols, geo, g, np.concatenate([fa, fb, f]))
        margin = weight[None] * ((fb - fa) ** 2)[:, None]
        bad = (np.maximum(Ga, Gb) + margin > LIMIT_TOL).any(axis=1)
        if not bad.any():
            return None
        fa, fb, Ga, Gb = fa[bad], fb[bad], Ga[bad], Gb[bad]
        fm = 0.5 * (fa + fb)
        G = g(fm)
        fa, fb = np.concatenate([fa, fm]), np.concatenate([fm, fb])
        Ga, Gb = np.concatenate([Ga, G]), np.concatenate([G, Gb])
    # pieces still within their (now tiny) margin of a wall: refuse, naming the closest
    margin = weight[None] * ((fb - fa) ** 2)[:, None]
    ub = np.maximum(Ga, Gb) + margin
    j, c = np.unravel_index(int(np.argmax(ub)), ub.shape)
    share = float(0.5 * (fa[j] + fb[j]))
    pose = (_frame_poses(geo, np.array([share])) @ geo.frame_from_flange)[0]
    return cons.violation(int(cols[c]), float(ub[j, c]), pose, share, certain=False)


def _worst_linear(cons: _Constraints, cols: np.ndarray, geo: _LinearGeometry,
                  g: Callable[[np.ndarray], np.ndarray], seen: np.ndarray) -> Violation:
    """The worst excursion of a linear move that does leave the envelope (fine sampling and
    the shares ``seen`` so far, for the message)."""
    f = np.concatenate([np.linspace(0.0, 1.0, 1001), seen])
    G = g(f)
    j, c = np.unravel_index(int(np.argmax(G)), G.shape)
    pose = (_frame_poses(geo, f[j:j + 1]) @ geo.frame_from_flange)[0]
    return cons.violation(int(cols[c]), float(G[j, c]), pose, float(f[j]))


# --- branch and bound --------------------------------------------------------------------------

def certify(g: Callable[[np.ndarray], np.ndarray], lo: np.ndarray, hi: np.ndarray,
            lipschitz: np.ndarray, tol: float = CERTIFY_TOL, budget: int = CERTIFY_BUDGET
            ) -> tuple[bool, np.ndarray, int, float, bool]:
    """Branch and bound: is every column of ``g`` ≤ 0 over the box [lo, hi] (d dims)?

    ``g`` maps points (n, d) to column values (n, C); ``lipschitz`` (C,) bounds how fast each
    column changes per unit of Euclidean distance in the box. A cell whose centre value plus
    lipschitz × half-diagonal is ≤ ``tol`` is inside; a centre value > LIMIT_TOL is a point
    outside. Returns (inside, x, column, value, certain): when not inside, x is a point outside
    (value > LIMIT_TOL, certain) or, when ``budget`` cells were spent, the centre of the worst
    cell left (its upper bound as value, not certain)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    L = np.asarray(lipschitz, float)
    centres, half = (0.5 * (lo + hi))[None], (0.5 * (hi - lo))[None]
    spent = 0
    while True:
        G = g(centres)
        spent += len(centres)
        if G.shape[1] == 0:
            return True, centres[0], -1, 0.0, True
        if (G > LIMIT_TOL).any():
            j, c = np.unravel_index(int(np.argmax(G)), G.shape)
            return False, centres[j], int(c), float(G[j, c]), True
        ub = G + L[None] * np.linalg.norm(half, axis=1)[:, None]
        open_ = (ub > tol).any(axis=1)
        if not open_.any():
            return True, centres[0], -1, float(ub.max()), True
        centres, half, ub = centres[open_], half[open_], ub[open_]
        if spent + 2 * len(centres) > budget:
            j, c = np.unravel_index(int(np.argmax(ub)), ub.shape)
            return False, centres[j], int(c), float(ub[j, c]), False
        ax = np.argmax(half, axis=1)
        rows = np.arange(len(centres))
        h = half.copy()
        h[rows, ax] *= 0.5
        off = np.zeros_like(centres)
        off[rows, ax] = h[rows, ax]
        centres = np.concatenate([centres - off, centres + off])
        half = np.concatenate([h, h])


# --- franky's per-axis Cartesian motion --------------------------------------------------------

def check_axis(env: Envelope, start: np.ndarray, target: np.ndarray,
               path: AxisPath) -> Violation | None:
    """The first limit that some pose of a franky Cartesian move's hull (module docstring)
    breaks, or None when the whole hull is inside. The hull contains every pose the move can
    take whatever each axis's profile, so this is conservative."""
    phi = np.asarray(path.flange_from_frame, float)
    frame_from_flange = invert(phi)
    A, B = np.asarray(start, float) @ phi, np.asarray(target, float) @ phi
    RA, a = A[:3, :3], A[:3, 3]
    du = RA.T @ (B[:3, 3] - a)                          # translation, start-frame axes
    dr = rotvec_from_matrix(RA.T @ B[:3, :3])           # rotation vector from the start
    cons = _Constraints(env)
    if len(cons) == 0:
        return None
    q = cons.points @ frame_from_flange[:3, :3].T + frame_from_flange[:3, 3]   # frame coords
    reach = np.linalg.norm(q, axis=1)
    M = RA * du[None, :]                                # column j: RA[:, j] · du_j
    up, down = np.clip(M, 0, None).sum(axis=1), np.clip(M, None, 0).sum(axis=1)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)]) * du
    corner_pos = a + corners @ RA.T                     # (8, 3) base frame

    def g(r: np.ndarray) -> np.ndarray:
        R = RA @ matrix_from_rotvec(r)                  # (n, 3, 3) frame rotations
        rot_pts = np.einsum("nij,kj->nki", R, q)        # (n, k, 3)
        cols = []
        if env.has_box:
            hi_pts = a + up + rot_pts                   # the farthest the translation goes
            lo_pts = a + down + rot_pts
            lo_b, hi_b = np.asarray(env.box_min_mm), np.asarray(env.box_max_mm)
            cols.append(np.stack([lo_b - lo_pts, hi_pts - hi_b], axis=-1).reshape(len(r), -1))
        if cons.offset:
            assert env.center is not None and env.max_offset_mm is not None
            p = corner_pos[None] + rot_pts[:, :1]        # flange origin at every corner
            d = np.linalg.norm(p - env.center[:3, 3], axis=2).max(axis=1)
            cols.append((d - env.max_offset_mm)[:, None])
        if cons.rotation:
            assert env.center is not None and env.max_rotation_deg is not None
            ang = angle_between(env.center[None, :3, :3], R @ phi[:3, :3].T)
            cols.append((ang - math.radians(env.max_rotation_deg))[:, None])
        return np.concatenate(cols, axis=1)

    L = np.array([1.0 if k == "rotation" else reach[max(i, 0)]
                  for k, i in zip(cons.kinds, cons.point, strict=True)])
    ok, r, col, value, certain = certify(g, np.minimum(dr, 0.0), np.maximum(dr, 0.0), L)
    if ok:
        return None
    pose = np.eye(4)
    pose[:3, :3] = RA @ matrix_from_rotvec(r) @ phi[:3, :3].T
    pose[:3, 3] = a - pose[:3, :3] @ phi[:3, 3]
    v = cons.violation(col, value, pose, None, certain)
    if cons.kinds[col] != "rotation":   # the translation's extreme corner of the hull
        return Violation(v.what, None, None, v.limit, v.excess, v.unit, v.certain)
    return v


# --- joint-space moves -------------------------------------------------------------------------

def check_joint_path(env: Envelope, fk: Callable[[np.ndarray], np.ndarray], q0: Sequence[float],
                     q1: Sequence[float], reach_mm: Sequence[float]) -> Violation | None:
    """The first limit a joint-interpolated move q(s) = q0 + s·(q1 − q0), s ∈ [0, 1], breaks,
    or None when all of it is inside. ``fk(q)`` gives base_from_flange (4×4 mm) for joints q
    (rad); ``reach_mm[i]`` bounds the distance (mm) from joint i's axis to the flange origin
    and to every tool point over the move (a revolute joint; for a prismatic one give 1 and
    its travel in mm as the joint value). Certified by branch and bound in s with the
    Lipschitz bound Σ|Δq_i|·reach_i mm (points) and Σ|Δq_i| rad (rotation) per unit of s."""
    q0a, q1a = np.asarray(q0, float), np.asarray(q1, float)
    reach = np.asarray(reach_mm, float)
    if q0a.shape != q1a.shape or reach.shape != q0a.shape or not np.isfinite(
            np.concatenate([q0a, q1a, reach])).all() or (reach < 0).any():
        raise ValueError("check_joint_path: q0, q1 and reach_mm must be finite, of one length, "
                         "reach ≥ 0")
    dq = q1a - q0a
    cons = _Constraints(env)
    if len(cons) == 0:
        return None
    L_pts = float(np.abs(dq) @ reach)
    L = np.where(cons.kind_arr == "rotation", float(np.abs(dq).sum()), L_pts)

    def poses(s: np.ndarray) -> np.ndarray:
        return np.array([fk(q0a + si * dq) for si in np.ravel(s)], dtype=np.float64)

    def g(s: np.ndarray) -> np.ndarray:
        return cons.values(poses(s))

    ok, s, col, value, certain = certify(g, np.zeros(1), np.ones(1), L)
    if ok:
        return None
    if certain:   # it does leave: report the worst of a fine sampling (and the point found)
        shares = np.append(np.linspace(0.0, 1.0, 1001), s[0])
        G = g(shares)
        j, c = np.unravel_index(int(np.argmax(G)), G.shape)
        s, col, value = shares[j:j + 1], int(c), float(G[j, c])
    share = float(s[0])
    return cons.violation(col, value, poses(np.array([share]))[0], share, certain)


def check_path(env: Envelope, start: np.ndarray, target: np.ndarray,
               path: LinearPath | AxisPath) -> Violation | None:
    """The first limit the move from flange ``start`` to flange ``target`` (4×4 mm) breaks on
    ``path``'s model, or None."""
    if isinstance(path, AxisPath):
        return check_axis(env, start, target, path)
    return check_linear(env, start, target, path)
