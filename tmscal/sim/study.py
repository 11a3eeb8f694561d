"""The simulation of Wang et al. (2018) (docs/methods.md): a truth, a plan of robot poses and
noisy observations from a :class:`~tmscal.sim.rig.SimRig`, for ``tmscal simulate``; optionally
with a serial arm whose true kinematics differ from its controller's (docs/kinematics.md)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .arm import ArmPair
from .rig import TMS_RIG_P0, Noise, SimRig, Truth, facing_start

#: with an arm, at most this many draws per pose asked for before the plan is given up (an
#: unreachable pose is re-drawn)
MAX_DRAWS_PER_POSE = 20


def simulate(n: int, rng: np.random.Generator, plan: str = "eq14", noise: Noise | None = None,
             truth: Truth | None = None, samples: int = 1, with_probe: bool = True,
             radius_mm: float | None = None, rotation_deg: float = 10.0,
             arm: ArmPair | None = None) -> tuple[Truth, dict[str, np.ndarray]]:
    """The simulation of Wang et al. (2018): a truth (random unless given), n poses by ``plan``
    ("random": fully random robot poses; "eq14": Eq. 14 around a P0 facing the tracker), and noisy
    observations, ``samples`` of them averaged per pose (chordal mean).

    With ``arm`` (an :class:`~tmscal.sim.arm.ArmPair`; :func:`_with_arm`) the robot moves a
    serial arm: joints by inverse kinematics on its NOMINAL model, A the nominal forward
    kinematics (plus the robot noise), B and C from the TRUE arm; the truth then carries the
    arm (``Truth.arm``) and the result the joints.

    Returns (truth, {"A", "commanded", "marker", ["probe"]}) with (n, 4, 4) mm arrays, and with
    an arm also "joints" (n, joints) rad and "redrawn" (a 0-d count of unreachable poses
    re-drawn). Raises ValueError for an unknown plan, or when an arm cannot reach enough of
    the plan's poses.
    """
    if plan not in ("random", "eq14"):
        raise ValueError(f"unknown plan {plan!r}; expected 'random' or 'eq14'")
    truth = truth or Truth.random(rng, with_probe=with_probe)
    if arm is not None:
        return _with_arm(n, rng, plan, noise or Noise(), replace(truth, arm=arm), samples,
                         radius_mm, rotation_deg)
    from ..poses import eq14_poses, random_poses

    if plan == "random":
        P = random_poses(n, rng, r_mm=500.0 if radius_mm is None else radius_mm)
    else:
        P = eq14_poses(facing_start(truth), n, rng, r_mm=100.0 if radius_mm is None
                       else radius_mm, d_deg=rotation_deg)
    rig = SimRig(truth, noise=noise or Noise(), rng=rng)
    out: dict[str, np.ndarray] = {"commanded": P, "A": np.empty_like(P)}
    for b in rig.bodies:
        out[b] = np.empty_like(P)
    for i, cmd in enumerate(P):
        rig.move_flange(cmd)
        out["A"][i] = rig.reported_flange()
        _observe(rig, out, i, samples)
    return truth, out


def _observe(rig: SimRig, out: dict[str, np.ndarray], i: int, samples: int) -> None:
    """Pose i of every body: one observation, or the chordal mean of ``samples``."""
    from ..geometry import pose_mean

    for b in rig.bodies:
        out[b][i] = rig.observe(b) if samples == 1 else pose_mean(rig.observe(b, samples))


def _with_arm(n: int, rng: np.random.Generator, plan: str, noise: Noise, truth: Truth,
              samples: int, radius_mm: float | None, rotation_deg: float
              ) -> tuple[Truth, dict[str, np.ndarray]]:
    """:func:`simulate` on a rig with the truth's arm, from the mock rig's start pose P0
    (``TMS_RIG_P0``: flange at (500, 0, 400) mm in the rig frame, tool down, which the arm's
    registry mount puts in its reach). Poses, one at a time: "eq14" Eq. 14 around P0 (±100 mm,
    ±10° unless given); "random" the nominal flange (rig frame) of joint configurations drawn
    uniformly within the joint limits (the arm's own "fully random" poses; ``radius_mm`` does
    not apply). A pose the arm cannot reach (no nominal inverse kinematics within the limits,
    as a controller refuses it) is RE-DRAWN, so the session has n poses; after
    ``MAX_DRAWS_PER_POSE`` × n draws, ValueError."""
    from ..poses import eq14_poses

    assert truth.arm is not None
    arm = truth.arm
    rig = SimRig(truth, noise=noise, rng=rng, start=TMS_RIG_P0, arm=arm)
    lim = arm.nominal.joint_limits_rad
    assert lim is not None  # Arm.__post_init__ sets ±2π for limits given as None
    out: dict[str, np.ndarray] = {"commanded": np.empty((n, 4, 4)), "A": np.empty((n, 4, 4)),
                                  "joints": np.empty((n, arm.nominal.n_joints))}
    for b in rig.bodies:
        out[b] = np.empty((n, 4, 4))
    draws = 0
    for i in range(n):
        while True:
            if draws >= MAX_DRAWS_PER_POSE * n:
                raise ValueError(f"the {arm.nominal.name} arm reached {i} of {draws} poses "
                                 f"drawn ({plan} plan); fewer than {n} are in its reach")
            draws += 1
            if plan == "eq14":
                cmd = eq14_poses(TMS_RIG_P0, 1, rng, r_mm=100.0 if radius_mm is None
                                 else radius_mm, d_deg=rotation_deg)[0]
            else:
                cmd = arm.reported(rng.uniform(lim[:, 0], lim[:, 1]))
            if rig.reach(cmd) is not None:
                break
        rig.move_flange(cmd)
        out["commanded"][i] = cmd
        out["A"][i] = rig.reported_flange()
        q = rig.joints()
        assert q is not None
        out["joints"][i] = q
        _observe(rig, out, i, samples)
    out["redrawn"] = np.array(draws - n)
    return truth, out
