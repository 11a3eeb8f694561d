"""Self-calibration of a recorded session (``tmscal selfcal identify``; docs/selfcal.md,
"Running it"): the joints and averaged wrenches of a session, the channel noise, which
parameters the gravity wrench identifies, and the identified arm (Joubair et al. 2016).

The arm written is the maximum a posteriori model of every parameter at once
(:func:`tmscal.calib.selfcal.identify.canonical`, ``form="map"``): what the wrench determines
comes from the data, what it sees only in a combination (θ0_2 + θ0_3 + θ0_4 of parallel
joints, θ0_6 and the sensor's yaw) is shared out as the prior says, so the answer does not
depend on which of several equivalent columns the identification keeps. ``form="kept"`` gives
the fit of the kept columns only (the others nominal), as the paper does.

Units: joints rad, wrenches [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame, lengths mm,
angles rad (the :meth:`ArmModel.vector` order and units).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..calib.kinematics import spec_by_name
from ..calib.selfcal.identify import (
    Fit,
    Identifiability,
    canonical,
    identifiable,
    identify,
    prior_scale,
)
from ..calib.selfcal.model import NOMINAL, ArmModel, jacobian
from ..errors import CalibrationError, SessionError
from ..session import Session

__all__ = ["CHANNELS", "CHANNEL_UNITS", "MIN_SIGMA", "FORMS", "SessionIdentification",
           "session_wrenches", "wrench_sigma", "identify_session"]

CHANNELS = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
CHANNEL_UNITS = ("N", "N", "N", "N·m", "N·m", "N·m")
#: the smallest channel σ used (N, N·m): a noise-free sensor (a mock without noise) would
#: otherwise give infinite weights
MIN_SIGMA = 1e-6
#: the forms of the written arm: the MAP model of every parameter, or the kept columns' fit
FORMS = ("map", "kept")


def session_wrenches(session: Session) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """(q (m, n) rad, wrench (m, 6), σ of each averaged wrench (m, 6; NaN without a recorded
    spread), pose indices) of the poses with joints and a wrench, ordered by index; the σ of a
    mean is its spread / √samples. SessionError when no pose has both."""
    use = sorted((p for p in session.poses if p.skipped is None and p.wrench is not None
                  and p.joints_rad is not None), key=lambda p: p.index)
    if not use:
        raise SessionError(f"{session.path}: no pose has both joint angles and a wrench "
                           "(record one with tmscal selfcal acquire)")
    idx = [p.index for p in use]
    q = session.joints(idx)
    w = np.array([p.wrench for p in use], dtype=float)
    sem = np.array([np.asarray(p.wrench_spread if p.wrench_spread is not None else [np.nan] * 6)
                    / math.sqrt(max(int(p.samples.get("wrench", 1)), 1)) for p in use])
    return q, w, sem, idx


def wrench_sigma(given: tuple[float, float] | None, sem: np.ndarray) -> tuple[np.ndarray, str]:
    """The channel noise (6,) N, N·m of the averaged wrenches and where it came from: the
    ``given`` (force N, torque N·m), else the RMS over poses of the recorded SD / √samples.
    CalibrationError when neither exists."""
    if given is not None:
        return np.array([given[0]] * 3 + [given[1]] * 3, dtype=float), "--sigma"
    if np.isnan(sem).all():
        raise CalibrationError("the session records no wrench spreads: give the channel "
                               "noise (--sigma FORCE_N TORQUE_NM)")
    s = np.sqrt(np.nanmean(sem ** 2, axis=0))
    return np.maximum(s, MIN_SIGMA), "the recorded spreads (SD / √samples, RMS over poses)"


@dataclass
class SessionIdentification:
    """What :func:`identify_session` found: the nominal ``model0`` and its registry ``name``;
    joints ``q`` (m, n) rad and ``indices``; the channel noise ``sigma`` (6,) and its
    ``sigma_source``; ``ident`` (which parameters the wrench identifies, and why not the
    others); ``fit`` (the kept columns' fit, its σ and residuals); ``scale`` the covariance
    factor max(1, reduced χ²); ``model`` the arm written (``form`` "map" or "kept");
    ``map_std`` the posterior σ of the identified parameters under the MAP's prior (their
    units), ``prior`` {"length_mm", "angle_deg"}."""

    name: str
    model0: ArmModel
    q: np.ndarray
    indices: list[int]
    sigma: np.ndarray
    sigma_source: str
    ident: Identifiability
    fit: Fit
    scale: float
    form: str
    model: ArmModel
    map_std: np.ndarray
    prior: dict[str, float]

    def record(self) -> dict[str, Any]:
        """The kinematics file's ``identification`` mapping (formats.kinfile): the identified
        parameters, the written model's values of them, their σ and covariance (of the kept
        columns' fit, scaled), the nominal values, and how the model was formed."""
        names = self.model0.parameter_names()
        pos = [names.index(n) for n in self.fit.parameters]
        p0, p1 = self.model0.vector(), self.model.vector()
        return {"nominal_arm": self.name, "form": self.form, "prior": dict(self.prior),
                "parameters": self.fit.parameters, "estimate": p1[pos],
                "std": self.fit.std * math.sqrt(self.scale), "nominal": p0[pos],
                "covariance": self.fit.covariance * self.scale,
                "covariance_scale": self.scale,
                "kept_estimate": self.fit.model.vector()[pos],
                "not_identified": dict(self.ident.removed), "iterations": self.fit.iterations,
                "converged": self.fit.converged, "reduced_chi2": float(self.fit.reduced_chi2),
                "sigma": dict(zip(CHANNELS, self.sigma.tolist(), strict=True)),
                "residual_rms": dict(zip(CHANNELS, self.fit.rms.tolist(), strict=True)),
                "configurations": len(self.q), "poses": self.indices}


def _posterior_std(model0: ArmModel, model: ArmModel, q: np.ndarray, sigma: np.ndarray,
                   tau: np.ndarray, names: list[str]) -> np.ndarray:
    """σ of ``names`` under the MAP's posterior (JᵀWJ + diag(τ⁻²))⁻¹ at ``model``."""
    Jw = jacobian(model, q) / np.tile(sigma, len(q))[:, None]
    P = np.linalg.inv(Jw.T @ Jw + np.diag(1.0 / tau ** 2))
    all_names = model0.parameter_names()
    return np.sqrt(np.clip([P[all_names.index(n), all_names.index(n)] for n in names], 0, None))


def identify_session(session: Session, arm: str, sigma: tuple[float, float] | None = None,
                     form: str = "map", prior_length_mm: float = 2.0,
                     prior_angle_deg: float = 1.0, max_iter: int = 50,
                     where: str = "--arm") -> SessionIdentification:
    """Identify the arm named ``arm`` (a registry name; ``where`` says where it came from)
    from the session's wrenches (module docstring). ``sigma`` the channel noise (N, N·m) or
    None (from the recorded spreads); ``form`` "map" or "kept"; the prior of the MAP form
    ±``prior_length_mm`` mm and ±``prior_angle_deg`` deg per parameter (1 N and 0.1 N·m for
    the weight and the bias). Raises SessionError (no usable pose, wrong joint count),
    CalibrationError (no noise, too few configurations, a failed fit), ConfigError (an
    unknown arm)."""
    if form not in FORMS:
        raise CalibrationError(f"selfcal: form must be one of {', '.join(FORMS)}, got {form!r}")
    model0 = NOMINAL[spec_by_name(arm, where).name]
    q, w, sem, idx = session_wrenches(session)
    src = session.path or "session"
    if q.shape[1] != model0.n_joints:
        raise SessionError(f"{src}: the poses have {q.shape[1]} joint angles; arm {arm} has "
                           f"{model0.n_joints}")
    sig, source = wrench_sigma(sigma, sem)
    names = model0.parameter_names()
    ident = identifiable(jacobian(model0, q) / np.tile(sig, len(q))[:, None], names)
    if 6 * len(q) <= len(ident.kept):
        raise CalibrationError(f"{src}: {len(q)} configurations give {6 * len(q)} equations "
                               f"for {len(ident.kept)} parameters; record more")
    try:
        fit = identify(model0, q, w, sig, ident, max_iter=max_iter)
        prior = {"length_mm": float(prior_length_mm), "angle_deg": float(prior_angle_deg)}
        model = (fit.model if form == "kept" else
                 canonical(model0, q, w, sig, start=fit.model, length_mm=prior_length_mm,
                           angle_deg=prior_angle_deg, max_iter=max_iter))
        tau = prior_scale(model0, prior_length_mm, prior_angle_deg)
        map_std = _posterior_std(model0, model, q, sig, tau, fit.parameters)
    except (ValueError, np.linalg.LinAlgError) as e:
        raise CalibrationError(f"{src}: the identification failed ({e})") from None
    return SessionIdentification(name=arm, model0=model0, q=q, indices=idx, sigma=sig,
                                 sigma_source=source, ident=ident, fit=fit,
                                 scale=max(1.0, float(fit.reduced_chi2)), form=form,
                                 model=model, map_std=map_std, prior=prior)
