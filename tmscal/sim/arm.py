"""A serial arm inside the sim rig: the robot's nominal kinematic model (what its controller
believes) and its true one (the nominal plus hidden parameter errors), for the mock robots of
issue 15's kinematic self-calibration (docs/selfcal.md, "On the rig").

A mock robot with an arm moves in joint space, as a real one does: a commanded flange pose
(base_from_flange, 4×4 mm) becomes joint angles q (rad) by inverse kinematics on the NOMINAL
model (:func:`inverse`: the one inverse kinematics, :mod:`tmscal.calib.kinematics.ik`);
the flange really goes where the TRUE model puts those joints (:meth:`ArmPair.actual`), and
the controller reports the nominal model's flange (:meth:`ArmPair.reported`), which is the
commanded pose to within the IK tolerance. The tracker therefore sees the true
arm's error and the controller never does: the robot's absolute error, which a hand/eye
calibration otherwise absorbs into X, Y and Z as best it can.

Hidden errors (:func:`make_arm`, the protocols ``ERROR_PROTOCOLS``): "paper" and "all" of the
size Joubair et al. (2016) simulate, uniform ±2 mm on lengths and ±1° on angles
(:func:`tmscal.calib.selfcal.model.perturb`); "realistic" of the size a real arm has:

* ``"paper"``: on the parameters the gravity wrench identifies only (their protocol: the
  others keep their nominal values), as :func:`tmscal.calib.selfcal.identify.identifiable`
  finds them on the nominal model's Jacobian over random configurations within the limits;
* ``"all"``: on every geometric parameter (each joint's θ0, d, a, α, the base's and the
  sensor mounting's orientation and position), the honest case: link lengths are not
  identifiable from the wrench and stay in error after self-calibration (the base position
  and yaw change neither the flange in the robot's frame nor the wrench: they are drawn
  and have no effect);
* ``"none"``: true = nominal (the arm moves in joint space, without kinematic error);
* ``"realistic"``: every geometric parameter of the arm in error at the size typical of that
  arm model WITHOUT a per-robot factory calibration (:func:`realistic_sigmas`), Gaussian:
  each joint's θ0, d, a, α, the Hayati angle β of each joint whose transform links parallel
  axes (``tmscal.calib.kinematics.jacobian.parallel_joints``: joints 2 and 3 of a UR, 2 of
  the VS-060), and the base and flange poses (roll, pitch, yaw, x, y, z each; these two are
  absorbed by the robot/world and hand/eye calibrations, drawn all the same). No
  manufacturer publishes such a per-model table; the ASSUMPTION (docs/kinematics.md,
  "Realistic arm errors") is length deviations N(0, σ_L²) with σ_L = 0.0004 × the arm's
  stated reach (``ArmSpec.reach_mm``: 0.34 mm on a UR5e, 0.52 mm on a UR10e, 0.7 mm on a
  UR20, 0.24 mm on the VS-060) and angle deviations N(0, (0.03°)²). On a UR5e this gives a
  mean flange error of 1.5 mm over the mock's workspace, and of 1.0 mm over the whole joint
  range once a rigid base and tool are fitted: the order Nubiola and Bonev (2013) measured
  on an uncalibrated ABB IRB 1600 (0.968 mm mean); ``benchmarks/realistic_arm_errors.py``
  prints it per arm. Here the base error moves the arm in the rig
  frame (the true chain starts at ``mount`` · nominal base⁻¹ · true base: where joint 1
  really is in the controller's base frame), and the flange error moves the flange.

Frames: an ArmModel's ``base`` is world ← robot base (world z up: a tilted mounting changes
the gravity the wrist sensor reads, not the flange pose in the robot's own frame), so a
controller computes base_from_flange = base⁻¹ · forward(model, q), the DH chain, as
``tmscal selfcal acquire`` and ``tmscal solve --kinematics`` do. The frame the mock controller
reports in, the rig's robot base frame (the frame of A and Z), is ``mount`` · robot base, from
the arm's registry entry (``tmscal.calib.kinematics.ARMS``, which says why each arm stands
where it does): identity for the UR5e; for the VS-060, whose 605 mm shoulder-to-wrist reach
leaves the shipped mock P0 (flange at (500, 0, 400) mm, tool down) near its edge, the robot
base stands at (150, 0, 0) mm in the rig's frame, like a DENSO work coordinate system, which
puts P0 and the Eq. 14 poses around it well inside the reach (:data:`ARM_MOUNTS`). The mount
is exact and part of the controller's setup, not a hidden error. Any registered arm can be
the mock's; one that cannot reach the start pose is refused (:class:`Unreachable`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..calib.kinematics import ARM_NAMES, ARMS, Arm
from ..calib.kinematics.ik import IK_TOL_MM, IK_TOL_RAD
from ..calib.kinematics.ik import inverse as ik_inverse
from ..calib.kinematics.jacobian import parallel_joints
from ..calib.selfcal.model import NOMINAL, ArmModel, forward, jacobian, perturb
from ..geometry import invert

__all__ = ["ArmPair", "Unreachable", "inverse", "reach", "make_arm", "realistic_sigmas",
           "ARM_MOUNTS", "HOME_Q", "ERROR_PROTOCOLS", "REALISTIC_LENGTH_PER_REACH",
           "REALISTIC_ANGLE_DEG", "IK_TOL_MM", "IK_TOL_RAD"]

#: the protocols of hidden arm errors :func:`make_arm` draws (module docstring)
ERROR_PROTOCOLS = ("paper", "all", "none", "realistic")
#: "realistic" errors: σ of every length deviation (mm) per mm of the arm's stated reach (an
#: assumption, module docstring: 0.34 mm on a UR5e's 850 mm)
REALISTIC_LENGTH_PER_REACH = 0.0004
#: "realistic" errors: σ of every angle deviation (θ0, α, β, base and flange rotations), deg
REALISTIC_ANGLE_DEG = 0.03

#: rig frame ← robot base for each arm, 4×4 mm: where the mock controller's reporting frame
#: puts the arm (module docstring; the registry entry's ``mount``)
ARM_MOUNTS: dict[str, np.ndarray] = {name: spec.mount for name, spec in ARMS.items()}
#: a joint configuration (rad) near the mock P0 with the tool pointing down, elbow up: the
#: seed of the first inverse kinematics (the registry entry's ``home_q``)
HOME_Q: dict[str, tuple[float, ...]] = {name: spec.home_q for name, spec in ARMS.items()}
#: fixed configurations :func:`reach` tries after the current joints and the home
_EXTRA_SEEDS = 12
#: random configurations that decide which parameters the wrench identifies ("paper")
_IDENT_CONFIGS = 60


class Unreachable(ValueError):
    """A commanded pose the arm cannot reach (no inverse kinematics within the joint
    limits); a mock controller refuses the move, as a real one refuses an unreachable
    target."""


@dataclass(frozen=True)
class ArmPair:
    """The arm of a sim rig: ``nominal`` (the controller's model) and ``true`` (the arm's
    real parameters), both :class:`~tmscal.calib.selfcal.model.ArmModel`; ``mount`` (4×4
    mm, rig frame ← robot base, exact; module docstring); ``home_q`` (rad) seeds the first
    inverse kinematics; ``errors`` names the protocol that made ``true`` ("paper", "all",
    "none", "realistic", or "custom") and ``perturbed`` the parameter names that carry errors.
    ``base_in_rig``: whether the true base's deviation from the nominal base moves the arm in
    the rig frame ("realistic"); otherwise each model's ``base`` is only its tilt against
    gravity (the wrench) and leaves the flange in the rig frame unchanged ("paper", "all")."""

    nominal: ArmModel
    true: ArmModel
    home_q: tuple[float, ...]
    errors: str = "custom"
    perturbed: tuple[str, ...] = ()
    mount: np.ndarray = field(default_factory=lambda: np.eye(4))
    base_in_rig: bool = False

    def flange(self, model: ArmModel, q: np.ndarray) -> np.ndarray:
        """base_from_flange (4×4 mm, the rig's frame) of ``model`` at joints ``q`` (rad):
        mount · base⁻¹ · forward(model, q), the base the nominal one when ``base_in_rig``
        (then a true base error moves the arm), else the model's own."""
        ref = self.nominal if self.base_in_rig else model
        return self.mount @ invert(ref.base) @ forward(model, q)

    def reported(self, q: np.ndarray) -> np.ndarray:
        """What the controller reports at joints ``q``: the NOMINAL flange (4×4 mm)."""
        return self.flange(self.nominal, q)

    def actual(self, q: np.ndarray) -> np.ndarray:
        """Where the flange really is at joints ``q``: the TRUE flange (4×4 mm)."""
        return self.flange(self.true, q)

    def geometry(self) -> tuple[Arm, Arm]:
        """(nominal, true) as plain :class:`~tmscal.calib.kinematics.Arm` (geometry only: DH
        rows, β, base, flange, joint limits; no sensor or tool), both in the controller's
        robot base frame, so that for either the flange in the rig frame is
        ``mount`` · ``forward(arm, q)`` (4×4 mm) at joints q (rad): the nominal's base is the
        identity, the true's the base error when ``base_in_rig``, else the identity."""
        base = invert(self.nominal.base) @ self.true.base if self.base_in_rig else np.eye(4)
        return _plain(self.nominal, np.eye(4)), _plain(self.true, base)

    def as_dict(self) -> dict[str, object]:
        """The session header's ``truth.arm`` (docs/session-format.md): {"name": the nominal
        arm's name (a registry name), "errors": ``errors``, "nominal", "true": ``Arm.to_dict``
        of :meth:`geometry` (mm, rad), "mount": 4×4 mm rig frame ← robot base}."""
        nominal, true = self.geometry()
        return {"name": self.nominal.name, "errors": self.errors, "nominal": nominal.to_dict(),
                "true": true.to_dict(), "mount": np.asarray(self.mount, dtype=float).tolist()}

    def solve(self, cmd: np.ndarray, q_now: np.ndarray | None) -> np.ndarray | None:
        """Joints (rad) at which the controller reports ``cmd`` (4×4 mm, rig frame):
        :func:`reach` on the nominal model from ``q_now``; None when out of reach."""
        target = self.nominal.base @ invert(self.mount) @ np.asarray(cmd, dtype=np.float64)
        return reach(self.nominal, target, q_now, self.home_q)


def _plain(model: Arm, base: np.ndarray) -> Arm:
    """The geometry of ``model`` as a plain Arm on ``base`` (4×4 mm)."""
    return Arm(name=model.name, dh=model.dh, base=base, joint_limits_rad=model.joint_limits_rad,
               convention=model.convention, flange=model.flange, beta=model.beta)


def inverse(model: ArmModel, target: np.ndarray, q0: np.ndarray,
            max_iter: int = 200) -> np.ndarray | None:
    """Joint angles q (rad) with forward(model, q) = ``target`` (world ← flange 4×4 mm)
    within ``IK_TOL_MM`` / ``IK_TOL_RAD``, inside the joint limits, from ``q0``: the one
    inverse kinematics, :func:`tmscal.calib.kinematics.ik.inverse` (damped least squares on
    the joint Jacobian), on base⁻¹ · target; None when it does not converge (out of
    reach, or only across a limit)."""
    base_inv = invert(np.asarray(model.base, dtype=np.float64))
    return ik_inverse(model, base_inv @ np.asarray(target, dtype=np.float64),
                      [np.asarray(q0, dtype=np.float64)], max_iter=max_iter)


def reach(model: ArmModel, target: np.ndarray, q_now: np.ndarray | None,
          home_q: tuple[float, ...]) -> np.ndarray | None:
    """:func:`inverse` of ``target`` (4×4 mm) from the current joints ``q_now`` (rad; the
    nearest solution, as a controller's move keeps its configuration), then from the arm's
    home, then from ``_EXTRA_SEEDS`` fixed configurations spread over the joint ranges (a
    target far from both, e.g. a self-calibration pose); None when none converges."""
    # no flange is farther from the base
    span = float(np.abs(model.dh[:, 1:3]).sum() + np.linalg.norm(model.flange[:3, 3]))
    if np.linalg.norm(np.asarray(target)[:3, 3] - model.base[:3, 3]) > span:
        return None
    seeds = ([] if q_now is None else [np.asarray(q_now, dtype=np.float64)]) \
        + [np.array(home_q, dtype=np.float64)]
    lim = model.joint_limits_rad
    assert lim is not None  # Arm.__post_init__ sets ±2π for limits given as None
    seeds += list(np.random.default_rng(1).uniform(lim[:, 0], lim[:, 1],
                                                   (_EXTRA_SEEDS, model.n_joints)))
    for q0 in seeds:
        q = inverse(model, target, q0)
        if q is not None:
            return q
    return None


@functools.lru_cache(maxsize=16)
def _identifiable_names(arm: str) -> tuple[str, ...]:
    """Names of the nominal ``arm``'s parameters the gravity wrench identifies, from the
    Jacobian over ``_IDENT_CONFIGS`` random configurations within the joint limits (a fixed
    draw: the answer does not depend on the mock's seed)."""
    from ..calib.selfcal.identify import identifiable
    model = NOMINAL[arm]
    rng = np.random.default_rng(12345)
    lim = model.joint_limits_rad
    assert lim is not None  # Arm.__post_init__ sets ±2π for limits given as None
    q = rng.uniform(lim[:, 0], lim[:, 1], (_IDENT_CONFIGS, model.n_joints))
    return tuple(identifiable(jacobian(model, q), model.parameter_names()).kept)


def _geometric_names(model: ArmModel) -> list[str]:
    """Every joint's θ0, d, a, α and the base's and sensor mounting's rpy and xyz."""
    return [n for n in model.parameter_names()
            if n.split("_")[0] in ("theta0", "d", "a", "alpha", "base", "sensor")]


def realistic_sigmas(arm: str) -> tuple[float, float]:
    """(σ_L mm, σ_angle rad) of the "realistic" errors of the registered ``arm``:
    ``REALISTIC_LENGTH_PER_REACH`` × its stated reach, and ``REALISTIC_ANGLE_DEG``."""
    return (REALISTIC_LENGTH_PER_REACH * ARMS[arm].reach_mm,
            math.radians(REALISTIC_ANGLE_DEG))


def _realistic(arm: str, rng: np.random.Generator) -> tuple[ArmModel, list[str]]:
    """The nominal ``arm`` with Gaussian errors on every geometric parameter (its geometry
    vector: each joint's θ0, d, a, α, the base's and the flange's roll, pitch, yaw, x, y, z)
    and on β of its parallel joints, sized by :func:`realistic_sigmas`; and their names."""
    nominal = NOMINAL[arm]
    sigma_l, sigma_a = realistic_sigmas(arm)
    sd = np.array([sigma_l if u == "mm" else sigma_a for u in nominal.geometry_units()])
    p = nominal.geometry_vector() + rng.normal(0.0, 1.0, len(sd)) * sd
    parallel = parallel_joints(nominal)
    assert nominal.beta is not None  # Arm.__post_init__ sets zeros for a β given as None
    beta = nominal.beta.copy()
    beta[[i - 1 for i in parallel]] += rng.normal(0.0, sigma_a, len(parallel))
    true = replace(nominal.with_geometry(p), beta=beta)
    return true, nominal.geometry_names() + [f"beta_{i}" for i in parallel]


def make_arm(arm: str, errors: str, seed: int) -> ArmPair:
    """The arm of a mock rig: the nominal ``arm`` (a registered name,
    ``tmscal.calib.kinematics.ARM_NAMES``), mounted at ``ARM_MOUNTS[arm]``, and its true
    model with the hidden ``errors`` ("paper", "all", "none" or "realistic"; module
    docstring) drawn from ``np.random.default_rng(seed)``."""
    if arm not in NOMINAL:
        raise ValueError(f"unknown arm {arm!r}; expected one of {', '.join(ARM_NAMES)}")
    nominal = NOMINAL[arm]
    if errors == "realistic":
        true, drawn = _realistic(arm, np.random.default_rng(seed))
        return ArmPair(nominal=nominal, true=true, home_q=HOME_Q[arm], errors=errors,
                       perturbed=tuple(drawn), mount=ARM_MOUNTS[arm].copy(), base_in_rig=True)
    if errors == "none":
        names: list[str] = []
    elif errors == "all":
        names = _geometric_names(nominal)
    elif errors == "paper":
        geometric = set(_geometric_names(nominal))
        names = [n for n in _identifiable_names(arm) if n in geometric]
    else:
        raise ValueError(f"unknown errors {errors!r}; expected one of "
                         f"{', '.join(ERROR_PROTOCOLS)}")
    true = (perturb(nominal, np.random.default_rng(seed), names) if names else nominal)
    return ArmPair(nominal=nominal, true=true, home_q=HOME_Q[arm], errors=errors,
                   perturbed=tuple(names), mount=ARM_MOUNTS[arm].copy())
