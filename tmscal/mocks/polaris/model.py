"""What the Polaris mock is configured with: the device models it can be, its measurement
volume and the faults it injects."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MODELS", "MeasurementVolume", "PolarisFaults"]

#: model name → frame rate (Hz) and the identity VER / GETINFO report.
MODELS: dict[str, dict[str, object]] = {
    "spectra": {"rate_hz": 60.0, "title": "Polaris Spectra Control Firmware",
                "freeze_tag": "Polaris Spectra Rev 007", "serial": "P6-00001"},
    "vicra": {"rate_hz": 20.0, "title": "Polaris Vicra Control Firmware",
              "freeze_tag": "Polaris Vicra Rev 007", "serial": "P5-00001"},
}


@dataclass(frozen=True)
class MeasurementVolume:
    """A frustum-shaped (pyramid) measurement volume in tracker coordinates, mm.

    The tracker looks along −z: a point (x, y, z) is inside when ``z_far_mm <= z <=
    z_near_mm`` and |x|, |y| are within half-widths that grow linearly from the near plane
    (``half_x_near_mm``, ``half_y_near_mm``) to the far plane (``half_x_far_mm``,
    ``half_y_far_mm``). Defaults resemble a Polaris Spectra pyramid, with generous widths.
    """

    z_near_mm: float = -950.0
    z_far_mm: float = -2400.0
    half_x_near_mm: float = 500.0
    half_x_far_mm: float = 900.0
    half_y_near_mm: float = 450.0
    half_y_far_mm: float = 800.0

    def __post_init__(self) -> None:
        if not self.z_far_mm < self.z_near_mm:
            raise ValueError(f"z_far_mm ({self.z_far_mm}) must be < z_near_mm "
                             f"({self.z_near_mm})")

    def contains(self, points_mm: np.ndarray) -> np.ndarray:
        """Boolean per point (k, 3) in tracker coordinates (mm): inside the volume?"""
        pts = np.atleast_2d(np.asarray(points_mm, dtype=np.float64))
        z = pts[:, 2]
        s = (self.z_near_mm - z) / (self.z_near_mm - self.z_far_mm)  # 0 near .. 1 far
        hx = self.half_x_near_mm + s * (self.half_x_far_mm - self.half_x_near_mm)
        hy = self.half_y_near_mm + s * (self.half_y_far_mm - self.half_y_near_mm)
        return ((z <= self.z_near_mm) & (z >= self.z_far_mm)
                & (np.abs(pts[:, 0]) <= hx) & (np.abs(pts[:, 1]) <= hy))


@dataclass(frozen=True)
class PolarisFaults:
    """Injected faults (all probabilities in [0, 1], drawn from the mock's seeded RNG).

    ``crc_error_prob``: a reply goes out with a corrupted CRC. ``drop_reply_prob``: a reply
    is not sent at all. Both apply to TX/BX replies only unless ``tracking_only`` is False
    (then to every reply). ``missing_fraction``: per frame and tool, the tool is reported
    MISSING. ``ir_interference_fraction``: per frame, every tool's port status gets 0x200
    (IR interference) and the system status 0x02 (too much IR); poses are still reported.
    ``unoccupied_fraction``: per frame and tool, the handle is reported ``UNOCCUPIED`` (TX;
    BX has no such status and says missing, port status 0), as when a wired tool is
    unplugged. ``bx_fails_from_tools``: when > 0, BX goes unanswered while at least this many
    handles are enabled, as BX does on the Polaris Spectra firmware revisions 006 and 007
    with three or more tools (scikit-surgerynditracker issues #53 and #67); TX still works.
    """

    crc_error_prob: float = 0.0
    drop_reply_prob: float = 0.0
    missing_fraction: float = 0.0
    ir_interference_fraction: float = 0.0
    tracking_only: bool = True
    unoccupied_fraction: float = 0.0
    bx_fails_from_tools: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.bx_fails_from_tools, bool) or not isinstance(
                self.bx_fails_from_tools, int) or self.bx_fails_from_tools < 0:
            raise ValueError(f"PolarisFaults.bx_fails_from_tools must be an int >= 0, got "
                             f"{self.bx_fails_from_tools!r}")
        for name in ("crc_error_prob", "drop_reply_prob", "missing_fraction",
                     "ir_interference_fraction", "unoccupied_fraction"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"PolarisFaults.{name} must be in [0, 1], got {v}")
