"""The wrench a mock force-torque sensor serves: the gravity wrench of the tool on the sim
rig's TRUE arm, noise-free, [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame.

With a kinematic arm in the rig (``mock.kinematics``: ``SimRig.arm_true`` and
``SimRig.joints()``), it is :func:`tmscal.calib.selfcal.model.wrench` of the true arm at the
current joints: the sensor mounting, the tool's weight and centre of gravity and the bias
are the true arm's. Without one, it is the gravity wrench of ``FALLBACK_TOOL`` hanging at
the rig's true flange, the sensor frame being the flange frame and the robot base frame
having z up: f = Rᵀ (0, 0, −m g), τ = c × f (R = base ← flange, c in m), no bias.

Both the ATI Net F/T mock and the UR mock's ``ft_raw_wrench`` / ``actual_TCP_force`` read
the same source, so they agree with each other and with the rig.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypedDict

import numpy as np

from ..calib.gravity import gravity_wrench
from ..sim.rig import SimRig

__all__ = ["FALLBACK_TOOL", "URWrenchOutputs", "gravity_wrench_source"]



class _Tool(TypedDict):
    mass_kg: float
    cog_mm: tuple[float, float, float]


#: the tool of a rig without a kinematic arm: mass (kg) and centre of gravity (mm, sensor
#: frame), a TMS coil-sized load
FALLBACK_TOOL: _Tool = {"mass_kg": 1.5, "cog_mm": (0.0, 0.0, 60.0)}


def gravity_wrench_source(rig: SimRig) -> Callable[[], np.ndarray]:
    """A callable returning the rig's noise-free sensor wrench now (see the module
    docstring)."""
    arm = getattr(rig, "arm_true", None)
    if arm is not None and hasattr(rig, "joints"):
        from ..calib.selfcal.model import wrench

        return lambda: np.asarray(wrench(arm, np.asarray(rig.joints())[None]),
                                  dtype=np.float64)[0]
    tool = FALLBACK_TOOL
    return lambda: gravity_wrench(rig.true_flange()[:3, :3], tool["mass_kg"], tool["cog_mm"])


class URWrenchOutputs:
    """The UR e-Series' two RTDE wrench outputs from one source (the mock UR controller's
    ``wrench``):

    * ``raw()`` — ``ft_raw_wrench``: the source plus Gaussian noise (``noise_n`` N per force
      channel, ``noise_nm`` N·m per torque channel), in the flange frame (the built-in
      sensor's frame), not payload-compensated, not zeroed;
    * ``tcp(base_from_flange)`` — ``actual_TCP_force``: a raw sample minus the gravity wrench
      of the payload the controller was told (``payload_kg`` at ``payload_cog_mm``, flange
      frame), rotated into the base frame by the controller's own flange pose (the mock's TCP
      is the flange). ``zero_ftsensor`` is not modelled.
    """

    def __init__(self, source: Callable[[], np.ndarray], noise_n: float = 0.0,
                 noise_nm: float = 0.0, payload_kg: float = 0.0,
                 payload_cog_mm: Any = (0.0, 0.0, 0.0), seed: int = 0) -> None:
        for name, v in (("noise_n", noise_n), ("noise_nm", noise_nm), ("payload_kg", payload_kg)):
            if not (isinstance(v, int | float) and np.isfinite(v) and v >= 0):
                raise ValueError(f"URWrenchOutputs: {name} must be a finite number ≥ 0, got "
                                 f"{v!r}")
        self.source = source
        self.noise = np.array([noise_n] * 3 + [noise_nm] * 3, dtype=np.float64)
        self.payload_kg = float(payload_kg)
        self.payload_cog_mm = np.asarray(payload_cog_mm, dtype=np.float64).reshape(3)
        self.rng = np.random.default_rng(seed)

    def raw(self) -> list[float]:
        """ft_raw_wrench: [F N, τ N·m], flange frame."""
        w = np.asarray(self.source(), dtype=np.float64).reshape(6)
        return [float(x) for x in w + self.rng.normal(0.0, 1.0, 6) * self.noise]

    def tcp(self, base_from_flange: np.ndarray) -> list[float]:
        """actual_TCP_force: [F N, τ N·m], base frame, payload compensated."""
        R = np.asarray(base_from_flange, dtype=np.float64)[:3, :3]
        ext = np.array(self.raw()) - gravity_wrench(R, self.payload_kg, self.payload_cog_mm)
        return [float(x) for x in np.concatenate([R @ ext[:3], R @ ext[3:]])]
