"""Force-torque self-calibration by the one kinematic estimator: the arm's deviations fitted to
the gravity wrenches a wrist sensor reads, with the wrench rows of the tracker-based estimate
(:mod:`tmscal.calib.kinematics.estimate`, :mod:`tmscal.calib.kinematics.wrench`) and no
tracker rows. Pure numerics, no I/O; docs/selfcal.md ("Running it").

The model is the one of the tracker-based estimate (docs/kinematics.md, "The estimator"): the
nominal arm p0 plus deviations δ of every DH parameter (θ0, d, a, α per joint, and the Hayati
angle β where consecutive axes are parallel), each with a Gaussian prior N(0, τ²) — the
tolerances, ±2 mm and ±1° by default, as the simulation protocol of Joubair et al. (2016)
draws its errors — and the 15 parameters of the wrench model without a prior (base tilt, the
sensor's rotation on the flange, the tool's weight and centre of gravity, the sensor's bias).
The estimate minimises Σ_i ‖(w(q_i; p0 + δ) − w_i)/σ‖² + Σ_j (δ_j/τ_j)², so what the wrenches
determine comes from them and what they do not see (every length; the combinations the base
tilt or the sensor's rotation absorb) stays at the nominal value, with minimum norm in
tolerance units: the answer does not depend on a choice of columns. The combinations it
identifies, weakly identifies or cannot identify, and why, come from the same SVD analysis
(:mod:`tmscal.calib.kinematics.identifiability`).

Frames and units: joints q (m, n) rad; wrenches [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor
frame; deviations mm or rad; the result an :class:`~tmscal.calib.selfcal.model.ArmModel`
(world ← base with the identified tilt, the nominal heading and position; the sensor mounting
with the identified rotation and the nominal offset, which no wrench sees).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ...geometry import make_pose
from ..gravity import G_STANDARD
from ..kinematics import pose_from_rpy, rpy_from_matrix
from ..kinematics.estimate import KinematicFit, fit_kinematics
from ..kinematics.levels import Tolerances
from ..kinematics.wrench import WrenchData
from .identify import check_data
from .model import ArmModel, wrench

__all__ = ["WrenchEstimate", "estimate_from_wrenches", "combination_record"]


@dataclass
class WrenchEstimate:
    """What :func:`estimate_from_wrenches` found: the identified ``model`` (an ArmModel), the
    estimator's ``fit`` (deviations ``fit.names``/``fit.delta``/``fit.sd`` rad or mm, the
    combinations, the wrench model's report ``fit.wrench``), the ``tolerances`` (the prior),
    the residual RMS per channel ``rms`` (6,) [N ×3, N·m ×3] and ``reduced_chi2`` (Σ (r/σ)²
    over the data rows / (rows − effective parameters): ≈ 1 when the stated σ is right)."""

    model: ArmModel
    fit: KinematicFit
    tolerances: Tolerances
    rms: np.ndarray
    reduced_chi2: float

    @property
    def covariance(self) -> np.ndarray:
        """Posterior covariance of the deviations ``fit.names`` (rad, mm), scaled by the
        variance factor as the estimator scales it."""
        k = len(self.fit.names)
        return self.fit.covariance[-k:, -k:] if k else np.zeros((0, 0))


def combination_record(c: Any) -> dict[str, Any]:
    """One :class:`~tmscal.calib.kinematics.identifiability.Combination` as plain data:
    terms, sigma_data, estimate, sd (tolerance units), reason and its one-line text."""
    return {"terms": c.terms, "sigma_data": c.sigma_data, "estimate": c.estimate, "sd": c.sd,
            "reason": c.reason, "text": c.describe()}


def estimate_from_wrenches(model0: ArmModel, q: Any, wrench_meas: Any, sigma: Any,
                           tolerances: Tolerances = Tolerances(2.0, 1.0), level: str = "full",
                           max_iter: int = 50) -> WrenchEstimate:
    """Identify ``model0``'s deviations (``level``: "full" every DH parameter and β,
    "offsets" the joint zero offsets only) from the wrenches ``wrench_meas`` (m, 6) [N, N·m,
    sensor frame] at joints q (m, n) rad, each channel with the noise ``sigma`` (6,) or
    (m, 6) of one averaged wrench, the prior ``tolerances`` (module docstring). Raises
    ValueError for malformed data, CalibrationError when the poses do not turn gravity
    enough in the sensor to separate the tool from the bias."""
    q, w, sig = check_data(model0, q, wrench_meas, sigma)
    data = WrenchData.make(w, sig, len(q))
    fit = fit_kinematics(q, [], model0, level, ([], np.eye(4)), {}, tolerances, max_iter,
                         wrench=data, noise_mode="given")
    assert fit.wrench is not None
    wp = fit.wrench["params"]
    yaw0 = rpy_from_matrix(model0.base)[2]
    chain = fit.chain   # model0 with the deviations: an ArmModel (with_deviations keeps it)
    assert isinstance(chain, ArmModel)
    model = replace(chain,
                    base=pose_from_rpy([wp.tilt[0], wp.tilt[1], yaw0], model0.base[:3, 3]),
                    flange_from_sensor=make_pose(wp.R_fs, model0.flange_from_sensor[:3, 3]),
                    tool_mass_kg=wp.mg / G_STANDARD, tool_cog_mm=wp.cog_mm, bias=wp.bias)
    rms = np.sqrt(np.mean((wrench(model, q) - w) ** 2, axis=0))
    return WrenchEstimate(model=model, fit=fit, tolerances=tolerances, rms=rms,
                          reduced_chi2=float(fit.variance_factor))
