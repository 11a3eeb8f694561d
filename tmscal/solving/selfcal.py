"""Self-calibration of a recorded session (``tmscal selfcal identify``; docs/selfcal.md,
"Running it"): the joints and averaged wrenches of a session, the channel noise, and the
identified arm.

Two forms. ``form="map"`` (the default) is the one kinematic estimator with wrench rows and no
tracker rows (:func:`tmscal.calib.selfcal.estimate.estimate_from_wrenches`): the maximum a
posteriori model of every DH deviation under a Gaussian prior (the tolerances), with the
combinations it identifies, weakly identifies or cannot identify and why — the same model,
loop and analysis as ``tmscal solve --kinematics estimate`` (docs/kinematics.md), so the
answer does not depend on a choice of columns. ``form="kept"`` is the protocol of Joubair et
al. (2016): the parameters QR column pivoting keeps are fitted, the others stay nominal
(:func:`tmscal.calib.selfcal.identify.identify`).

Units: joints rad, wrenches [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame, lengths mm,
angles rad (the :meth:`ArmModel.vector` order and units).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..calib.kinematics import spec_by_name
from ..calib.kinematics.levels import Tolerances
from ..calib.kinematics.solve import wrench_summary
from ..calib.selfcal.estimate import (
    WrenchEstimate,
    combination_record,
    estimate_from_wrenches,
)
from ..calib.selfcal.identify import Fit, Identifiability, identifiable, identify
from ..calib.selfcal.model import NOMINAL, ArmModel, jacobian
from ..errors import CalibrationError, SessionError
from ..session import Session

__all__ = ["CHANNELS", "CHANNEL_UNITS", "MIN_SIGMA", "FORMS", "SessionIdentification",
           "session_wrenches", "wrench_sigma", "nominal_model", "identify_session"]

CHANNELS = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
CHANNEL_UNITS = ("N", "N", "N", "N·m", "N·m", "N·m")
#: the smallest channel σ used (N, N·m): a noise-free sensor (a mock without noise) would
#: otherwise give infinite weights
MIN_SIGMA = 1e-6
#: the forms of the written arm: the estimator's MAP model of every deviation, or the paper's
#: fit of the kept columns (module docstring)
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
    ``sigma_source``; ``form`` ("map" or "kept") and the arm written, ``model``; ``prior``
    {"length_mm", "angle_deg"} (the estimator's tolerances). With ``form="map"``:
    ``estimate``, the estimator's result (deviations, combinations, wrench model). With
    ``form="kept"``: ``ident`` (which parameters QR pivoting keeps, and why not the others),
    ``fit`` (their fit, σ and residuals) and ``scale`` the covariance factor
    max(1, reduced χ²)."""

    name: str
    model0: ArmModel
    q: np.ndarray
    indices: list[int]
    sigma: np.ndarray
    sigma_source: str
    form: str
    model: ArmModel
    prior: dict[str, float]
    estimate: WrenchEstimate | None = None
    ident: Identifiability | None = None
    fit: Fit | None = None
    scale: float = 1.0

    @property
    def rms(self) -> np.ndarray:
        """Residual RMS per channel (6,) N ×3, N·m ×3 of the written model's fit."""
        if self.estimate is not None:
            return self.estimate.rms
        assert self.fit is not None
        return self.fit.rms

    @property
    def reduced_chi2(self) -> float:
        if self.estimate is not None:
            return self.estimate.reduced_chi2
        assert self.fit is not None
        return float(self.fit.reduced_chi2)

    @property
    def iterations(self) -> int:
        if self.estimate is not None:
            return self.estimate.fit.iterations
        assert self.fit is not None
        return self.fit.iterations

    def record(self) -> dict[str, Any]:
        """The kinematics file's ``identification`` mapping (formats.kinfile): the estimated
        parameters, the written model's values of them, their σ and covariance, the nominal
        values, and how the model was formed (``method: wrench`` and the estimator's
        combinations for the MAP form; the kept columns and why the others were not for the
        paper's)."""
        common = {"nominal_arm": self.name, "form": self.form, "prior": dict(self.prior),
                  "reduced_chi2": float(self.reduced_chi2), "iterations": self.iterations,
                  "sigma": dict(zip(CHANNELS, self.sigma.tolist(), strict=True)),
                  "residual_rms": dict(zip(CHANNELS, self.rms.tolist(), strict=True)),
                  "configurations": len(self.q), "poses": self.indices}
        if self.estimate is not None:
            est = self.estimate
            f = est.fit
            return {**common, "method": "wrench", "level": f.level,
                    "tolerances": dict(self.prior), "parameters": list(f.names),
                    "estimate": [self.model.deviation(n) for n in f.names],
                    "nominal": [self.model0.deviation(n) for n in f.names],
                    "std": f.sd, "covariance": est.covariance,
                    "identified": [combination_record(c) for c in f.identified],
                    "weak": [combination_record(c) for c in f.weak],
                    "unidentified": [combination_record(c) for c in f.unidentified],
                    "variance_factor": f.variance_factor,
                    "wrench": wrench_summary(f)}
        assert self.fit is not None and self.ident is not None
        names = self.model0.parameter_names()
        pos = [names.index(n) for n in self.fit.parameters]
        p0, p1 = self.model0.vector(), self.model.vector()
        return {**common, "parameters": self.fit.parameters, "estimate": p1[pos],
                "std": self.fit.std * math.sqrt(self.scale), "nominal": p0[pos],
                "covariance": self.fit.covariance * self.scale,
                "covariance_scale": self.scale,
                "not_identified": dict(self.ident.removed),
                "converged": self.fit.converged}


def nominal_model(arm: Any, where: str = "--arm") -> ArmModel:
    """The self-calibration model to start from: the registry's (``NOMINAL``) for a registered
    name, else the arm a shipped arm file, a URDF, an arm file or an ``ArmDefinition`` defines
    (:func:`tmscal.formats.armdef.resolve_arm`) with the sensor on the flange and the default
    tool. ConfigError naming ``where`` for an unknown name or an arm self-calibration cannot
    take (a passive, mimicking row); CalibrationError naming the file for a file that is not an
    arm."""
    from ..calib.kinematics.arms import ARMS
    from ..errors import ConfigError
    from ..formats.armdef import ArmDefinition, resolve_arm

    if isinstance(arm, str) and arm in ARMS:
        return NOMINAL[spec_by_name(arm, where).name]
    if isinstance(arm, ArmDefinition) and arm.kind == "registry":
        return NOMINAL[arm.name]
    d = arm if isinstance(arm, ArmDefinition) else resolve_arm(arm, where)
    try:
        return ArmModel.from_arm(d.arm)
    except ValueError as e:
        raise ConfigError(f"{where}: {e}") from None


def identify_session(session: Session, arm: Any, sigma: tuple[float, float] | None = None,
                     form: str = "map", prior_length_mm: float = 2.0,
                     prior_angle_deg: float = 1.0, max_iter: int = 50,
                     where: str = "--arm") -> SessionIdentification:
    """Identify the arm ``arm`` names (a registry name, a shipped arm file's, or the path of a
    URDF or arm file: :func:`nominal_model`; ``where`` says where it came from)
    from the session's wrenches (module docstring). ``sigma`` the channel noise (N, N·m) or
    None (from the recorded spreads); ``form`` "map" (the estimator) or "kept" (the paper's
    protocol); the prior of the MAP form ±``prior_length_mm`` mm and ±``prior_angle_deg``
    deg per deviation. Raises SessionError (no usable pose, wrong joint count),
    CalibrationError (no noise, too few configurations, a failed fit), ConfigError (an
    unknown arm)."""
    if form not in FORMS:
        raise CalibrationError(f"selfcal: form must be one of {', '.join(FORMS)}, got {form!r}")
    model0 = nominal_model(arm, where)
    arm = model0.name
    q, w, sem, idx = session_wrenches(session)
    src = session.path or "session"
    if q.shape[1] != model0.n_joints:
        raise SessionError(f"{src}: the poses have {q.shape[1]} joint angles; arm {arm} has "
                           f"{model0.n_joints}")
    sig, source = wrench_sigma(sigma, sem)
    prior = {"length_mm": float(prior_length_mm), "angle_deg": float(prior_angle_deg)}
    common: dict[str, Any] = {"name": arm, "model0": model0, "q": q, "indices": idx,
                              "sigma": sig, "sigma_source": source, "form": form,
                              "prior": prior}
    if form == "map":
        if len(q) < 4:
            raise CalibrationError(f"{src}: {len(q)} configurations; the wrench model alone "
                                   "has 15 parameters: record more")
        try:
            est = estimate_from_wrenches(model0, q, w, sig,
                                         Tolerances(prior_length_mm, prior_angle_deg),
                                         max_iter=max_iter)
        except (ValueError, np.linalg.LinAlgError) as e:
            raise CalibrationError(f"{src}: the identification failed ({e})") from None
        except CalibrationError as e:
            raise CalibrationError(f"{src}: {e}") from None
        return SessionIdentification(**common, model=est.model, estimate=est)
    names = model0.parameter_names()
    ident = identifiable(jacobian(model0, q) / np.tile(sig, len(q))[:, None], names)
    if 6 * len(q) <= len(ident.kept):
        raise CalibrationError(f"{src}: {len(q)} configurations give {6 * len(q)} equations "
                               f"for {len(ident.kept)} parameters; record more")
    try:
        fit = identify(model0, q, w, sig, ident, max_iter=max_iter)
    except (ValueError, np.linalg.LinAlgError) as e:
        raise CalibrationError(f"{src}: the identification failed ({e})") from None
    return SessionIdentification(**common, model=fit.model, ident=ident, fit=fit,
                                 scale=max(1.0, float(fit.reduced_chi2)))
