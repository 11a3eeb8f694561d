"""A linear move of the UR mock's flange: interpolation along the straight line and the
rotation geodesic, and the TCP speed it implies."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...geometry import matrix_from_rotvec, rotvec_from_matrix


@dataclass
class Motion:
    """A linear move of the flange (base_from_flange 4×4 mm) under way."""

    start: np.ndarray          # base_from_flange 4×4 mm at the start
    target: np.ndarray         # base_from_flange 4×4 mm commanded
    t0: float
    duration: float            # s
    asynchronous: bool
    speed: float               # m/s (rad/s for rotation-only moves)
    stop_fraction: float | None = None   # a fault stops the motion at this fraction
    stop_kind: str = "protective"        # that fault: "protective" stop or "power_off"

    def fraction(self, now: float) -> float:
        if self.duration <= 0:
            return 1.0
        return min(1.0, max(0.0, (now - self.t0) / self.duration))

    def pose_at(self, f: float) -> np.ndarray:
        """Interpolated base_from_flange (mm): translation lerp, rotation along the geodesic."""
        if f >= 1.0:
            return self.target.copy()
        out = np.eye(4)
        out[:3, 3] = self.start[:3, 3] + f * (self.target[:3, 3] - self.start[:3, 3])
        rel = self.start[:3, :3].T @ self.target[:3, :3]
        out[:3, :3] = self.start[:3, :3] @ matrix_from_rotvec(f * rotvec_from_matrix(rel))
        return out

    def velocity(self, now: float) -> list[float]:
        """TCP speed [vx, vy, vz (m/s), wx, wy, wz (rad/s)] in the base frame (zero when
        done)."""
        if self.duration <= 0 or self.fraction(now) >= 1.0:
            return [0.0] * 6
        v = (self.target[:3, 3] - self.start[:3, 3]) / 1000.0 / self.duration
        rel = self.start[:3, :3].T @ self.target[:3, :3]
        w = self.start[:3, :3] @ rotvec_from_matrix(rel) / self.duration
        return [float(x) for x in (*v, *w)]
