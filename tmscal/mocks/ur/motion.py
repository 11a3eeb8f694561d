"""A linear move of the UR mock's TCP on a trapezoidal velocity profile (:mod:`tmscal.motion`):
the straight line and the rotation geodesic of the TCP, both driven by one path parameter, the
flange that follows from it (``flange_from_tcp``; identity: TCP = flange), and the TCP speed
it implies.

The caps are ``movel``'s: tool speed ``speed`` (m/s) and acceleration ``accel`` (m/s²) for
the translation, and ``ROTATION_FACTOR`` (4) times the same numbers as rad/s and rad/s² for
the rotation, as a UR controller derives them for ``movel`` (answer on the Universal Robots
forum, "MoveL: Tool Angular Speed", 2021; not in UR's script manual: CHECK at a rig). A
profile is fitted to the translation distance and one to the rotation angle (here the
geodesic angle); the move takes the longer (:func:`tmscal.motion.move_duration` with these
caps) and the other part is slowed to that duration by following the same path parameter:
the share covered of the governing profile (``Trapezoid.fraction``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...geometry import invert, rotvec_from_matrix
from ...motion import Trapezoid
from ...sim.rig import straight_path

#: the rotation caps of a movel: this many rad/s (rad/s²) per m/s (m/s²) of the tool caps
ROTATION_FACTOR = 4.0
#: the step (s) of the central difference that gives the TCP speed from the profile
_DT = 1e-4


@dataclass
class Motion:
    """A linear move of the TCP (base_from_tcp 4×4 mm) under way, started at ``t0`` (the
    mock clock's seconds). ``modelled_s`` is the profile's duration (s) on every clock;
    ``duration`` is 0 when ``instant`` (the fast clock: the move completes at once).
    ``flange_from_tcp`` (4×4 mm) is the controller's TCP offset: ``pose_at`` gives the
    flange."""

    start: np.ndarray          # base_from_tcp 4×4 mm at the start
    target: np.ndarray         # base_from_tcp 4×4 mm commanded
    t0: float
    asynchronous: bool
    speed: float               # m/s (× ROTATION_FACTOR: rad/s for the rotation)
    accel: float               # m/s² (× ROTATION_FACTOR: rad/s² for the rotation)
    instant: bool = False
    stop_fraction: float | None = None   # a fault stops the motion at this fraction
    stop_kind: str = "protective"        # that fault: "protective" stop or "power_off"
    flange_from_tcp: np.ndarray = field(default_factory=lambda: np.eye(4))
    modelled_s: float = field(init=False)
    _profile: Trapezoid = field(init=False, repr=False)

    def __post_init__(self) -> None:
        d_mm = float(np.linalg.norm(self.target[:3, 3] - self.start[:3, 3]))
        angle = float(np.linalg.norm(self._rotvec()))
        translation = Trapezoid(d_mm, self.speed * 1000.0, self.accel * 1000.0)
        rotation = Trapezoid(angle, ROTATION_FACTOR * self.speed, ROTATION_FACTOR * self.accel)
        # the governing profile; its duration is move_duration(start, target, 1000 v,
        # 1000 a, degrees(4 v), degrees(4 a)) (a profile's duration does not depend on the unit)
        self._profile = max(translation, rotation, key=lambda p: p.duration)
        self.modelled_s = self._profile.duration

    @property
    def duration(self) -> float:
        """Seconds the move lasts on the mock's clock (0 on the fast clock)."""
        return 0.0 if self.instant else self.modelled_s

    def _rotvec(self) -> np.ndarray:
        return rotvec_from_matrix(self.start[:3, :3].T @ self.target[:3, :3])

    def _share(self, t: float) -> float:
        """The path parameter (0…1) ``t`` s after the start."""
        return self._profile.fraction(t)

    def fraction(self, now: float) -> float:
        """The share of the path covered at ``now`` (0…1, on the trapezoid, not linear in
        time)."""
        if self.duration <= 0:
            return 1.0
        return self._share(now - self.t0)

    def tcp_at(self, f: float) -> np.ndarray:
        """base_from_tcp (mm) at path share ``f``: the straight line for the translation, the
        geodesic for the rotation."""
        return straight_path(self.start, self.target, f)

    def pose_at(self, f: float) -> np.ndarray:
        """base_from_flange (mm) at path share ``f`` (the TCP's path carried to the
        flange)."""
        return self.tcp_at(f) @ invert(self.flange_from_tcp)

    def pose_at_time(self, t: float) -> np.ndarray:
        """base_from_flange (mm) ``t`` s after the start on the modelled profile (on the fast
        clock too, where the move itself is instant): what the controller executes, for a
        trajectory recorder."""
        return self.pose_at(self._share(t))

    def velocity(self, now: float) -> list[float]:
        """TCP speed [vx, vy, vz (m/s), wx, wy, wz (rad/s)] in the base frame (zero when
        done): the path's direction times the rate of the path parameter (a central
        difference of the profile)."""
        if self.duration <= 0 or self.fraction(now) >= 1.0:
            return [0.0] * 6
        t = now - self.t0
        rate = (self._share(t + _DT) - self._share(max(t - _DT, 0.0))) / (t + _DT
                                                                         - max(t - _DT, 0.0))
        v = (self.target[:3, 3] - self.start[:3, 3]) / 1000.0 * rate
        w = self.start[:3, :3] @ self._rotvec() * rate
        return [float(x) for x in (*v, *w)]
