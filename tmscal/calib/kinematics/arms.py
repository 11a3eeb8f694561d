"""The one registry of nominal arms: every arm tmscal knows by name, its nominal kinematic model
from the manufacturer's published values (cited per entry), what its controller calls it, and
the mock rig's placement of it. Self-calibration, configs (``mock.kinematics.arm``), the CLI's
``--arm`` and the mock robots all read this list; docs/kinematics.md has the table.

Names are the model as the vendor writes it, in lower case: ``ur3``, ``ur5``, ``ur10`` (CB3),
``ur3e``, ``ur5e``, ``ur10e``, ``ur16e``, ``ur20``, ``vs060``, ``cobotta``, ``fr3``, ``panda``.

Sources (values converted to mm and rad):

* Universal Robots: "DH Parameters for calculations of kinematics and dynamics", Universal
  Robots A/S support article (standard DH per model, CB3 and e-Series; the UR20 table from
  2023). Joint ranges: the models' user manuals ("Technical specifications", Universal
  Robots 2015–2023): ±360° on every joint (UR3/UR3e: the last one turns without limit, kept
  at ±360° here); the elbow is limited to ±180° here, the range the arm can physically use
  (the shoulder is in the way beyond it), as the previous tmscal model did.
* Franka: "Robot and interface specifications", Franka Control Interface documentation
  (Franka Emika 2017–2023; Franka Robotics for the FR3): modified DH (Craig 1989) of joints
  1–7 and the flange (d = 107 mm), the same for Panda and FR3; the joint limits of each.
  q = 0 is the arm straight up with joint 4 at 0, outside its range (a mathematical zero,
  not a reachable pose); the flange frame is Franka's F.
* DENSO publishes link lengths, not DH parameters, for the VS-060 and COBOTTA: the tables
  here are APPROXIMATIONS derived by hand from the joint origins and axes of DENSO's own ROS
  descriptions (DENSO WAVE: denso_robot_ros, ``vs060.urdf``, 2017; denso_cobotta_ros,
  ``cobotta.urdf``, 2019), with the joint limits given there; q = 0 is the arm straight up
  with the flange frame parallel to the base frame, as in those descriptions.
* Reach (``reach_mm``, the maximum reach each manufacturer states; it sizes the mock rig's
  realistic arm errors, ``tmscal.sim.arm``): Universal Robots' user manuals, "Technical
  specifications" (UR3/UR3e 500 mm, UR5/UR5e 850 mm, UR10/UR10e 1300 mm, UR16e 900 mm, UR20
  1750 mm); DENSO WAVE's product specifications (VS-060 605 mm, to the wrist centre;
  COBOTTA 342.5 mm); Franka's "Robot and interface specifications" (855 mm, Panda and FR3).

Mock placement (``mount``, ``home_q``): where the mock rig puts the arm so that its start pose
``tmscal.sim.TMS_RIG_P0`` (flange at (500, 0, 400) mm in the rig frame, tool down) and the plan
around it (±100 mm, ±10°) lie inside the reach, like a robot's base placed for the task:
``mount`` is rig frame ← robot base (4×4 mm, exact, part of the controller's setup) and
``home_q`` (rad) a configuration near that start with the tool down, elbow up, that seeds the
first inverse kinematics. Every arm here reaches P0 so placed, and every pose of a 60-pose
Eq. 14 plan around it except the COBOTTA (342 mm from shoulder to wrist: 55 of 60; the mock
refuses the others as a controller would, and the acquisition stops there). A start pose
(``plan.start``) out of an arm's reach is a ConfigError naming ``mock.kinematics``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from ...errors import ConfigError
from ...geometry import make_pose, rot_z
from .model import Arm

__all__ = ["ArmSpec", "ARMS", "ARM_NAMES", "arm_by_name", "spec_by_name", "find_arm",
           "UR_SOURCE", "FRANKA_SOURCE", "DENSO_SOURCE"]

UR_SOURCE = ("Universal Robots A/S, \"DH Parameters for calculations of kinematics and "
             "dynamics\" (support article, CB3 and e-Series; UR20 2023); joint ranges from the "
             "user manuals' technical specifications")
FRANKA_SOURCE = ("Franka Emika / Franka Robotics, \"Robot and interface specifications\", "
                 "Franka Control Interface documentation (2017–2023): modified DH and joint "
                 "limits")
DENSO_SOURCE = ("approximation derived from DENSO WAVE's ROS descriptions (denso_robot_ros "
                "vs060.urdf, 2017; denso_cobotta_ros cobotta.urdf, 2019): DENSO publishes no "
                "DH parameters")

_H = math.pi / 2
_FULL = 2 * math.pi


@dataclass(frozen=True)
class ArmSpec:
    """One registered arm: its nominal ``arm`` (an :class:`~.model.Arm`, base = identity: the
    world is the robot's base frame), ``vendor`` ("Universal Robots", "DENSO", "Franka"),
    ``model`` as the vendor writes it ("UR5e", "VS-060", "FR3"), ``source`` (the citation),
    ``approximate`` (True: not the manufacturer's own DH table), ``controller_model`` (what the
    controller calls it: UR's dashboard ``get robot model`` answer, DENSO's ``@TYPE_NAME``,
    the robot name in the URDF a Franka controller returns), ``generation`` (UR: "CB3",
    "e-Series", or None when the model alone tells), ``mock_serial`` (the serial number a mock
    controller answers), the mock rig's ``mount`` (rig ← robot base, 4×4 mm) and ``home_q``
    (rad) (module docstring), and ``reach_mm``: the maximum reach the manufacturer states (mm;
    module docstring), which sizes the mock's realistic arm errors (``tmscal.sim.arm``)."""

    arm: Arm
    vendor: str
    model: str
    source: str
    controller_model: str
    approximate: bool = False
    generation: str | None = None
    mock_serial: str | None = None
    mount: np.ndarray = field(default_factory=lambda: np.eye(4))
    home_q: tuple[float, ...] = ()
    reach_mm: float = 0.0

    def __post_init__(self) -> None:
        mount = np.array(self.mount, dtype=float)
        if mount.shape != (4, 4):
            raise ValueError(f"{self.arm.name}: mount must be 4×4")
        object.__setattr__(self, "mount", mount)
        if len(self.home_q) != self.arm.n_joints:
            raise ValueError(f"{self.arm.name}: home_q must have {self.arm.n_joints} values")
        object.__setattr__(self, "home_q", tuple(float(v) for v in self.home_q))

    @property
    def name(self) -> str:
        """The registry name (lower case)."""
        return self.arm.name


def _ur(name: str, model: str, d1: float, a2: float, a3: float, d4: float, d5: float,
        d6: float, generation: str | None, serial: str, reach_mm: float,
        mount_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> ArmSpec:
    """A UR arm from its six published lengths (metres in UR's table, mm here)."""
    dh = [[0.0, d1, 0.0, _H], [0.0, 0.0, a2, 0.0], [0.0, 0.0, a3, 0.0],
          [0.0, d4, 0.0, _H], [0.0, d5, 0.0, -_H], [0.0, d6, 0.0, 0.0]]
    lim = [[-_FULL, _FULL]] * 2 + [[-math.pi, math.pi]] + [[-_FULL, _FULL]] * 3
    arm = Arm(name=name, dh=np.array(dh), joint_limits_rad=np.array(lim))
    return ArmSpec(arm=arm, vendor="Universal Robots", model=model, source=UR_SOURCE,
                   controller_model=model.rstrip("e") if generation == "e-Series" else model,
                   generation=generation, mock_serial=serial,
                   mount=make_pose(np.eye(3), mount_xyz), reach_mm=reach_mm,
                   home_q=(math.pi, -_H, _H, -_H, -_H, 0.0))


#: the modified DH rows of Franka's arms (Panda and FR3 alike), [θ0 rad, d mm, a mm, α rad]
_FRANKA_DH = np.array([[0.0, 333.0, 0.0, 0.0], [0.0, 0.0, 0.0, -_H], [0.0, 316.0, 0.0, _H],
                       [0.0, 0.0, 82.5, _H], [0.0, 384.0, -82.5, -_H], [0.0, 0.0, 0.0, _H],
                       [0.0, 0.0, 88.0, _H]])
_FRANKA_FLANGE = make_pose(np.eye(3), [0.0, 0.0, 107.0])


def _franka(name: str, model: str, lo: list[float], hi: list[float]) -> ArmSpec:
    arm = Arm(name=name, dh=_FRANKA_DH, convention="modified", flange=_FRANKA_FLANGE,
              joint_limits_rad=np.column_stack([lo, hi]))
    return ArmSpec(arm=arm, vendor="Franka", model=model, source=FRANKA_SOURCE,
                   controller_model=name, home_q=(0.0, -0.11, 0.0, -2.28, 0.0, 2.17, 0.0),
                   reach_mm=855.0)


_SPECS: tuple[ArmSpec, ...] = (
    # Universal Robots CB3 (PolyScope 3.x) and e-Series (PolyScope 5.x)
    # the UR3s' 500 mm reach: the base stands 200 mm nearer P0, on a 100 mm pedestal
    _ur("ur3", "UR3", 151.9, -243.65, -213.25, 112.35, 85.35, 81.9, "CB3", "2015330001", 500.0,
        (200.0, 0.0, 100.0)),
    _ur("ur5", "UR5", 89.159, -425.0, -392.25, 109.15, 94.65, 82.3, "CB3", "2016351864", 850.0),
    _ur("ur10", "UR10", 127.3, -612.0, -572.3, 163.941, 115.7, 92.2, "CB3", "2016301779", 1300.0),
    _ur("ur3e", "UR3e", 151.85, -243.55, -213.2, 131.05, 85.35, 92.1, "e-Series",
        "20185300000", 500.0, (200.0, 0.0, 100.0)),
    _ur("ur5e", "UR5e", 162.5, -425.0, -392.2, 133.3, 99.7, 99.6, "e-Series", "20185500000", 850.0),
    _ur("ur10e", "UR10e", 180.7, -612.7, -571.55, 174.15, 119.85, 116.55, "e-Series",
        "20185000000", 1300.0),
    _ur("ur16e", "UR16e", 180.7, -478.4, -360.0, 174.15, 119.85, 116.55, "e-Series",
        "20195600000", 900.0),
    # the UR20's controller answers "UR20": the model alone tells (no CB3 twin); UR publishes
    # its serial-number structure only as a figure, so the mock's number is made up
    _ur("ur20", "UR20", 236.3, -862.0, -728.7, 201.0, 159.3, 154.3, None, "20230000001", 1750.0),
    ArmSpec(
        arm=Arm(name="vs060",
                dh=np.array([[0.0, 345.0, 0.0, -_H], [-_H, 0.0, 305.0, 0.0],
                             [-_H, 0.0, 10.0, -_H], [0.0, 300.0, 0.0, _H],
                             [0.0, 0.0, 0.0, -_H], [math.pi, 70.0, 0.0, 0.0]]),
                joint_limits_rad=np.array([[-2.96706, 2.96706], [-2.094395, 2.094395],
                                           [-2.181662, 2.70526], [-4.712389, 4.712389],
                                           [-2.094395, 2.094395], [-6.283185, 6.283185]])),
        vendor="DENSO", model="VS-060", source=DENSO_SOURCE, controller_model="VS-060",
        approximate=True, mount=make_pose(np.eye(3), [150.0, 0.0, 0.0]),
        home_q=(0.0, 0.5, 1.5, 0.0, 1.14, 0.0), reach_mm=605.0),
    ArmSpec(
        arm=Arm(name="cobotta",
                dh=np.array([[0.0, 180.0, 0.0, -_H], [-_H, 0.0, 165.0, 0.0],
                             [-_H, 20.0, 12.0, -_H], [0.0, 177.5, 0.0, _H],
                             [0.0, -64.5, 0.0, -_H], [math.pi, 42.0, 0.0, 0.0]]),
                joint_limits_rad=np.array([[-2.617994, 2.617994], [-1.047198, 1.745329],
                                           [0.3141593, 2.443461], [-2.96706, 2.96706],
                                           [-1.658063, 2.356194], [-2.96706, 2.96706]])),
        vendor="DENSO", model="COBOTTA", source=DENSO_SOURCE, controller_model="COBOTTA",
        # beside P0 (turned −90° about z, on a 200 mm pedestal): the wrist then works in the
        # middle of its ±170° J6 range
        approximate=True, mount=make_pose(rot_z(-_H), [500.0, 200.0, 200.0]),
        home_q=(0.22, 0.28, 1.93, 0.0, 0.93, 1.8), reach_mm=342.5),
    _franka("fr3", "FR3", [-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159],
            [2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159]),
    _franka("panda", "Panda", [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973],
            [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]),
)

#: every registered arm by name (read-only)
ARMS: Mapping[str, ArmSpec] = MappingProxyType({s.name: s for s in _SPECS})
#: the registered names, in the registry's order
ARM_NAMES: tuple[str, ...] = tuple(ARMS)


def spec_by_name(name: Any, where: str = "--arm") -> ArmSpec:
    """The registry entry named ``name``; ConfigError naming ``where`` and the known names
    otherwise."""
    spec = ARMS.get(name) if isinstance(name, str) else None
    if spec is None:
        shown = repr(name) if isinstance(name, str) and len(name) <= 40 else \
            f"{type(name).__name__} value"
        raise ConfigError(f"{where}: unknown arm {shown}; expected one of: "
                          f"{', '.join(ARM_NAMES)}")
    return spec


def arm_by_name(name: Any, where: str = "--arm") -> Arm:
    """The nominal :class:`~.model.Arm` named ``name`` (mm, rad; base = identity);
    ConfigError naming ``where`` and the known names otherwise."""
    return spec_by_name(name, where).arm


def find_arm(vendor: str, controller_model: str | None,
             generation: str | None = None) -> str | None:
    """The registry name of ``vendor``'s arm whose controller calls it ``controller_model``
    (compared case-insensitively, spaces, hyphens and underscores ignored). ``generation``
    (UR: "CB3" or "e-Series"; None: unknown) keeps the entries of that generation (an entry
    whose generation is None matches any). None when no entry, or more than one, matches
    (e.g. "UR5" of an unknown generation: the CB3 UR5 or the UR5e)."""
    if not controller_model:
        return None

    def key(s: str) -> str:
        return "".join(c for c in s.lower() if c.isalnum())

    want = key(controller_model)
    hits = [s for s in _SPECS if s.vendor == vendor and key(s.controller_model) == want]
    if generation is not None:
        hits = [s for s in hits if s.generation in (None, generation)]
    return hits[0].name if len(hits) == 1 else None
