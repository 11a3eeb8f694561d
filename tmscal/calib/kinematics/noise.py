"""The noise of the kinematic fit estimated from its own residuals, as ``ml`` estimates it
(docs/methods.md, "Noise from the data"; docs/kinematics.md, "The estimator").

The variance components are ``ml``'s (:mod:`tmscal.calib.variance`): the robot's rotation
noise (rad² per axis of its flange rotation vector) and translation noise (mm² per component),
carried through X (and Y) into each pose's residual, and — only when neither sample spreads nor
a tracker covariance give the tracker's noise — the tracker's level (a factor on its
covariance). They are estimated by restricted maximum likelihood (Förstner 1979) from the data
rows' raw residuals and Jacobian at the estimate. The prior on the arm's deviations enters as
what it is: rows of known unit variance (the pseudo-observations δ/τ), passed to
:func:`~tmscal.calib.variance.estimate_components` as ``fixed`` rows — so the directions of δ
that the data cannot see are held by the prior instead of making the normal matrix singular,
and the prior's residuals are not counted as data noise.

The noise is carried as ``ml``'s option dictionary (robot_sigma_mm, robot_sigma_deg,
tracker_sigma_mm/deg, tracker_cov, spreads): an estimate is again such a dictionary, which is
how the cross-validation's fits take it as given.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import CalibrationError
from ..ml_model import robot_parts, tracker_covs, tracker_part
from ..variance import COMPONENTS, Components, estimate_components

__all__ = ["NOISE_MODES", "FLOOR", "estimated_components", "theta_of", "factors",
           "with_factors", "components", "noise_report", "log_det",
           "log_dets"]

#: how the kinematic fit sets the noise (``ml``'s option of the same name)
NOISE_MODES = ("estimate", "given")


def estimated_components(noise: dict[str, Any], mode: str) -> np.ndarray:
    """Which of :data:`~tmscal.calib.variance.COMPONENTS` ``mode`` estimates (3,) bool:
    with "estimate" the robot's two, and the tracker's level only without spreads and
    tracker_cov (``ml``'s rule); none with "given"."""
    if mode not in NOISE_MODES:
        raise CalibrationError(f"kinematics: unknown noise {mode!r}; expected "
                               f"{' or '.join(NOISE_MODES)}")
    on = mode == "estimate"
    tracker = on and noise.get("spreads") is None and noise.get("tracker_cov") is None
    return np.array([on, on, tracker])


def theta_of(noise: dict[str, Any]) -> np.ndarray:
    """The factors θ (3,) of a noise dictionary: robot rotation rad² (per axis), robot
    translation mm² (per component), the tracker's factor 1 (on the dictionary's own)."""
    rad = np.radians(float(noise["robot_sigma_deg"]))
    return np.array([rad * rad, float(noise["robot_sigma_mm"]) ** 2, 1.0])


def factors(noise: dict[str, Any], n: int, nb: int) -> tuple[np.ndarray, np.ndarray]:
    """(θ (3,): robot rotation rad², robot translation mm², tracker factor 1; T the tracker's
    residual covariance, (q, q) shared or (n, q, q) per pose, q = 6·bodies) of a noise
    dictionary for n poses of nb bodies."""
    T = tracker_part(tracker_covs(n, ["marker", "probe"][:nb], noise))
    if noise.get("spreads") is None:
        T = T[0]
    return theta_of(noise), T


def with_factors(noise: dict[str, Any], theta: np.ndarray) -> dict[str, Any]:
    """The noise dictionary of the factors θ (:func:`factors`' order): the robot's sigmas
    √θ, the tracker's sigmas times √θ_tracker (a tracker_cov or spreads are never scaled:
    their level is not estimated)."""
    out = dict(noise)
    out["robot_sigma_deg"] = float(np.degrees(np.sqrt(theta[0])))
    out["robot_sigma_mm"] = float(np.sqrt(theta[1]))
    if theta[2] != 1.0:
        f = float(np.sqrt(theta[2]))
        out["tracker_sigma_mm"] = float(noise["tracker_sigma_mm"]) * f
        out["tracker_sigma_deg"] = float(noise["tracker_sigma_deg"]) * f
    return out


def components(r: np.ndarray, J: np.ndarray, m: int, Ws: list[np.ndarray],
               noise: dict[str, Any], estimate: np.ndarray, given: dict[str, Any]
               ) -> Components:
    """The REML components at an estimate from its raw (unwhitened) residual vector ``r``
    and Jacobian ``J`` (rows: the m data residuals, pose by pose [rot rad; trans mm] per
    body, then rows already whitened by their known variance — the prior's δ/τ), X (and Y)
    ``Ws`` 4×4 mm and the noise dictionary ``noise`` the factors start from (θ relative to
    its tracker level); no factor goes below :data:`FLOOR` times the ``given`` noise's."""
    nb = len(Ws)
    q = 6 * nb
    n = m // q
    theta, T = factors(noise, n, nb)
    Qr, Qt = robot_parts(Ws)
    t0 = theta_of(given)
    level = (float(noise["tracker_sigma_mm"]) / float(given["tracker_sigma_mm"])) ** 2
    return estimate_components(J[:m].reshape(n, q, -1), r[:m].reshape(n, q), [Qr, Qt, T],
                               theta, estimate, fixed=(J[m:], r[m:]),
                               floor=FLOOR * np.array([t0[0], t0[1], 1.0 / level]))


#: the smallest noise an estimate may reach, as a fraction of the given variance (σ ≥ 1 % of
#: the given σ): noise-free data would otherwise drive it to zero round after round
FLOOR = 1e-4


def log_dets(whiten: np.ndarray, n: int) -> np.ndarray:
    """ln det S_i (n,) of the residual covariances whose whitener (L⁻¹, triangular: one
    (q, q) shared by the n poses or (n, q, q)) is given: the likelihood's normalisation."""
    d = -2.0 * np.sum(np.log(np.abs(np.diagonal(whiten, axis1=-2, axis2=-1))), axis=-1)
    return np.broadcast_to(d, (n,)).astype(float)


def log_det(whiten: np.ndarray, n: int) -> float:
    """Σ_i ln det S_i (:func:`log_dets`)."""
    return float(np.sum(log_dets(whiten, n)))


def noise_report(mode: str, given: dict[str, Any], final: dict[str, Any],
                 comp: Components | None, rounds: int) -> dict[str, Any]:
    """``cal.extra["noise"]`` as ``ml`` reports it: the mode, the robot's σ (mm, degrees)
    used, where the tracker's noise came from and its factor on the given one, which
    components were estimated, their effective degrees of freedom, and the rounds of
    estimate → refit; ``scale_covariance``: the covariance scaled by the variance factor
    (with the noise as given)."""
    tracker = "spreads" if given.get("spreads") is not None else \
        ("tracker_cov" if given.get("tracker_cov") is not None else "sigmas")
    factor = (float(final["tracker_sigma_mm"]) / float(given["tracker_sigma_mm"])) ** 2
    est = comp.estimated if comp is not None else np.zeros(3, bool)
    dof = {} if comp is None else {c: float(v) for c, v in zip(COMPONENTS, comp.dof,
                                                                 strict=True)
                                   if np.isfinite(v)}
    return {"mode": mode, "robot_sigma_mm": float(final["robot_sigma_mm"]),
            "robot_sigma_deg": float(final["robot_sigma_deg"]), "tracker": tracker,
            "tracker_factor": factor,
            "tracker_sigma_mm": float(final["tracker_sigma_mm"]),
            "tracker_sigma_deg": float(final["tracker_sigma_deg"]),
            "estimated": [c for c, e in zip(COMPONENTS, est, strict=True) if e],
            "dof": dof, "rounds": rounds, "scale_covariance": mode == "given"}
