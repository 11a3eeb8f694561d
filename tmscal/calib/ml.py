"""Maximum-likelihood calibration on SE(3) with an optional tracker distortion (``ml``).

Frames and units as everywhere (docs/conventions.md): A = base_from_flange, B =
tracker_from_marker, C = tracker_from_probe, X = flange_from_marker, Y = flange_from_probe,
Z = base_from_tracker; 4×4, mm.

Model. The robot's flange really sits at A_i δ_i (δ_i a small rigid error, rotation vector
N(0, σ_r² I) rad in the flange frame, translation N(0, σ_t² I) mm), and the tracker reports
each body with an error ε in the body frame (rotation and translation, covariance Σ_ε, 6×6).
The tracker may be distorted: a 3×3 map D acts on tracker-frame positions (measured = D ·
true) and the tracker fits each tool rigidly to its distorted fiducials, so a measured pose
is undone by G = D⁻¹ (:func:`undistort`). Per pose and body the residual is

    E = (A_i W)⁻¹ Z Ñ_i,  r = [log R(E) (rad); t(E) (mm)]   (W = X or Y, Ñ undistorted)

and to first order r = Ad-like(W) δ + ε, so the residuals of one pose (marker and probe share
δ) have the covariance S = J_W Σ_δ J_Wᵀ + blockdiag(Σ_ε), which whitens them. ``ml``
minimises Σ r_iᵀ S_i⁻¹ r_i by Levenberg–Marquardt (numerical Jacobian, columns scaled), S
re-evaluated at the estimate once, started from QR36 (QR24 on marker-only data). D is "none",
"scale" (isotropic), "axis" (per-axis scale) or "affine" (symmetric 3×3: per-axis scale and
shear; a rotation part of D would turn positions and orientations alike and is Z's rotation,
so it is not identifiable and not a parameter); "auto" fits all four and keeps the one with
the smallest information criterion, with the noise level profiled out: AIC = m ln(χ²/m) + 2k
by default (m residuals, k parameters), or BIC = m ln(χ²/m) + k ln m (``criterion="bic"``).
AIC because it is asymptotically equivalent to leave-one-out cross-validation (Stone 1977),
i.e. it keeps a distortion when held-out data support it; BIC's ln m penalty is consistent but
conservative. Measured on the simulated rig (Eq. 14 plan, 250 training poses, a tracker with
per-axis scale 1.001/0.999/1 and a 0.05 % shear; 4 sessions): AIC chose "affine" and held
out 0.191 mm, BIC chose "axis" and held out 0.195 mm; without a distortion (n = 20) both
chose "none" in 59–60 of 60 sessions at the same held-out error.

Noise. Options ``robot_sigma_mm`` (per component) and ``robot_sigma_deg`` (per axis of the
rotation vector), ``tracker_sigma_mm`` and ``tracker_sigma_deg`` (per component of the
tracked pose), or ``tracker_cov`` (6×6, body frame, [rot rad; trans mm]); ``spreads`` (one
session pose record per pose, with "spread" {body: {trans_mm, rot_deg}} and "samples") sets
the tracker noise per pose from the session's sample spreads instead (σ = spread / √3 /
√samples per component). The defaults (robot 0.05 mm and 0.03° per axis, tracker 0.025 mm
and 0.05° per axis) are the simulated rig's noise for one sample per pose (Wang et al. 2018:
0.05 mm fiducial noise on an NDI 8700340-like tool). These give the relative weights; by default
(``scale_covariance=True``) the covariance is also multiplied by the a-posteriori variance
factor χ²/(m − k), so the absolute level is estimated from the residuals.

``tools_mm`` (the tools' fiducials, (k, 3) mm, one array or {body: array}) lets the
orientation be undistorted as the tracker's rigid fit distorts it (:func:`undistort`); without
it the tool is taken as isotropic.

Parameters (``extra["parameters"]``): per transform X, (Y,) Z, a rotation vector ω (rad) on
the right, R = R̂ exp([ω]×), and a translation offset (mm, parent frame); then the
distortion's undistortion parameters g (dimensionless; G = I + …).
"""

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import CalibrationError
from ..geometry import make_pose, orthonormalize
from .bound import uncertainty_at
from .calibration import Applied, Calibration
from .methods import register_method, solve
from .ml_model import (
    DISTORTION_MODELS,
    Problem,
    check_sigma,
    covariance_from_jacobian,
    g_of,
    noise_covariance,
    parameter_names,
    tool_moment,
    tracker_covs,
    whiten_residuals,
    whitener,
)

__all__ = ["ml_solve", "fit_model", "Fit", "levenberg_marquardt"]


def levenberg_marquardt(prob: Problem, whiten: np.ndarray, th: np.ndarray,
                        max_iter: int = 50) -> tuple[np.ndarray, np.ndarray, int]:
    """Minimise the whitened χ²; returns (θ, whitened Jacobian at θ, iterations)."""
    r = whiten_residuals(whiten, prob.residuals(th)).ravel()
    cost = r @ r
    lam = 1e-6
    for it in range(1, max_iter + 1):
        J = prob.jacobian(th, whiten)
        d = np.linalg.norm(J, axis=0)
        d[d == 0] = 1.0
        Js = J / d
        H, g = Js.T @ Js, Js.T @ r
        while True:
            step = np.linalg.solve(H + lam * np.eye(len(th)), -g)
            new = th + step / d
            r_new = whiten_residuals(whiten, prob.residuals(new)).ravel()
            c_new = r_new @ r_new
            if c_new <= cost or lam > 1e8:
                break
            lam *= 10
        if c_new > cost:
            return th, J, it
        done = cost - c_new <= 1e-12 * max(cost, 1e-300) + 1e-30 or \
            np.linalg.norm(step) < 1e-12 * np.sqrt(len(th))
        th, r, cost, lam = new, r_new, c_new, max(lam / 10, 1e-12)
        if done:
            break
    return th, prob.jacobian(th, whiten), it


@dataclass
class Fit:
    """One fitted model: the problem re-centred at the estimate (θ = 0), the whitened
    Jacobian there, the covariance (unscaled, noise as given), χ² and counts."""

    prob: Problem
    J: np.ndarray
    P: np.ndarray
    chi2: float
    m: int
    iterations: int

    def criterion(self, name: str) -> float:
        """The information criterion ("aic" or "bic") with the noise level profiled out:
        m ln(χ²/m) + 2k (AIC) or + k ln m (BIC)."""
        k = self.prob.n_params
        fit = self.m * np.log(max(self.chi2 / self.m, 1e-30))
        return fit + (2.0 * k if name == "aic" else k * np.log(self.m))


def fit_model(A: np.ndarray, bodies: list[np.ndarray], Ws: list[np.ndarray], Z0: np.ndarray,
              model: str, noise: tuple[float, float, np.ndarray], max_iter: int = 50,
              moments: list[np.ndarray | None] | None = None) -> Fit:
    """Fit one distortion model from the start (Ws, Z0); ``noise`` = (robot σ mm, robot σ
    rad, tracker covariances (n, m, 6, 6)). The noise covariance is evaluated at the start and
    once more at the estimate."""
    prob = Problem(A, bodies, Ws, Z0, model, moments=moments)
    m = A.shape[0] * 6 * len(bodies)
    if prob.n_params >= m:
        raise CalibrationError(f"distortion model {model!r} has {prob.n_params} parameters "
                               f"but {A.shape[0]} poses give only {m} residuals")
    its = 0
    for _ in range(2):
        Ws_now, Z, G = prob.unpack(np.zeros(prob.n_params))
        whiten = whitener(noise_covariance(Ws_now, noise[0], noise[1], noise[2]))
        th, _, it = levenberg_marquardt(prob, whiten, np.zeros(prob.n_params), max_iter)
        its += it
        Ws_new, Z, G = prob.unpack(th)
        prob = Problem(A, bodies, Ws_new, Z, model, g_of(model, G), moments)
    th0 = np.zeros(prob.n_params)
    J = prob.jacobian(th0, whiten)
    P = covariance_from_jacobian(J, f"the ml model (distortion {model!r})")
    r = whiten_residuals(whiten, prob.residuals(th0)).ravel()
    return Fit(prob, J, P, float(r @ r), m, its)


def _noise(n: int, names: list[str], opts: dict[str, Any]
           ) -> tuple[float, float, np.ndarray]:
    rs_mm = check_sigma("robot_sigma_mm", opts["robot_sigma_mm"])
    rs_rad = np.radians(check_sigma("robot_sigma_deg", opts["robot_sigma_deg"]))
    return rs_mm, rs_rad, tracker_covs(n, names, opts)


def _select(A: np.ndarray, bodies: list[np.ndarray], Ws: list[np.ndarray], Z0: np.ndarray,
            distortion: str, noise: tuple[float, float, np.ndarray], max_iter: int,
            moments: list[np.ndarray | None], criterion: str) -> tuple[Fit, dict[str, float]]:
    """Fit the requested model, or with "auto" every identifiable one and keep the lowest
    criterion; returns (fit, {model: criterion})."""
    if distortion != "auto":
        f = fit_model(A, bodies, Ws, Z0, distortion, noise, max_iter, moments)
        return f, {distortion: f.criterion(criterion)}
    fits = {}
    for model in DISTORTION_MODELS:
        try:
            fits[model] = fit_model(A, bodies, Ws, Z0, model, noise, max_iter, moments)
        except CalibrationError:
            if model == "none":
                raise
    bics = {k: f.criterion(criterion) for k, f in fits.items()}
    return fits[min(bics, key=bics.__getitem__)], bics


def _moments(tools_mm: Any, names: list[str]) -> list[np.ndarray | None]:
    """Per body the tool's second moment from ``tools_mm``: None, one (k, 3) array for every
    body, or {body name: (k, 3)}."""
    if tools_mm is None:
        return [None] * len(names)
    if isinstance(tools_mm, dict):
        return [None if tools_mm.get(nm) is None else tool_moment(tools_mm[nm])
                for nm in names]
    M = tool_moment(tools_mm)
    return [M] * len(names)


@register_method("ml")
def ml_solve(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, orthonormal: bool,
             distortion: str = "auto", robot_sigma_mm: float = 0.05,
             robot_sigma_deg: float = 0.03, tracker_sigma_mm: float = 0.025,
             tracker_sigma_deg: float = 0.05, tracker_cov: Any = None, spreads: Any = None,
             tools_mm: Any = None, criterion: str = "aic", scale_covariance: bool = True,
             max_iter: int = 50, kinematics: str | None = None, joints: Any = None,
             arm: Any = None, level: str = "auto", tolerances: Any = None,
             folds: int = 5) -> Calibration:
    """Maximum-likelihood X, (Y,) Z with tracker distortion ``distortion`` ("auto" by BIC,
    "none", "scale", "axis", "affine"); see the module docstring for the model, the noise
    options and the parameters. The raw matrices carry the distortion (Z_raw = Z · G, G =
    D⁻¹), as QR24's absorb it; ``errors`` undoes it either way.

    ``kinematics="estimate"`` estimates the arm's kinematics with X, Y, Z in the same
    likelihood (:mod:`tmscal.calib.kinematics.solve`, docs/kinematics.md): ``joints`` (n, dof)
    rad, ``arm`` the nominal model (an ``Arm`` or a registry name such as "ur5e"), ``level``
    ("auto", "none", "offsets", "full"), ``tolerances`` (a ``Tolerances``: the prior), ``folds``
    of the held-out level choice; ``distortion`` then "none" (default with kinematics) or a
    fixed model ("auto" is not searched with the arm)."""
    if kinematics is not None:
        from .kinematics.solve import solve_with_kinematics

        if kinematics != "estimate":
            raise CalibrationError(f"method 'ml': unknown kinematics {kinematics!r}; expected "
                                   "'estimate' (or none)")
        return solve_with_kinematics(
            A, B, C, joints=joints, arm=arm, level=level, tolerances=tolerances, folds=folds,
            distortion="none" if distortion == "auto" else distortion, tools_mm=tools_mm,
            robot_sigma_mm=robot_sigma_mm, robot_sigma_deg=robot_sigma_deg,
            tracker_sigma_mm=tracker_sigma_mm, tracker_sigma_deg=tracker_sigma_deg,
            tracker_cov=tracker_cov, spreads=spreads, orthonormal=orthonormal)
    if distortion not in DISTORTION_MODELS and distortion != "auto":
        raise CalibrationError(f"method 'ml': unknown distortion {distortion!r}; expected "
                               f"auto, {', '.join(DISTORTION_MODELS)}")
    if criterion not in ("aic", "bic"):
        raise CalibrationError(f"method 'ml': unknown criterion {criterion!r}; expected aic "
                               "or bic")
    start = solve(A, B, C, method="qr24" if C is None else "qr36")
    bodies = [B] if C is None else [B, C]
    names = ["marker"] if C is None else ["marker", "probe"]
    opts = {"robot_sigma_mm": robot_sigma_mm, "robot_sigma_deg": robot_sigma_deg,
            "tracker_sigma_mm": tracker_sigma_mm, "tracker_sigma_deg": tracker_sigma_deg,
            "tracker_cov": tracker_cov, "spreads": spreads}
    noise = _noise(len(A), names, opts)
    Ws0 = [start.X] if C is None else [start.X, start.Y]
    moments = _moments(tools_mm, names)
    fit, bics = _select(A, bodies, Ws0, start.Z, distortion, noise, int(max_iter), moments,
                        criterion)
    k = fit.prob.n_params
    vf = fit.chi2 / (fit.m - k)
    P = fit.P * vf if scale_covariance else fit.P
    Ws, Z, G = fit.prob.unpack(np.zeros(k))
    D = np.linalg.inv(G)
    G4 = np.eye(4)
    G4[:3, :3] = G
    N_ref = make_pose(orthonormalize(bodies[-1][:, :3, :3].mean(axis=0)),
                      bodies[-1][:, :3, 3].mean(axis=0))
    u = uncertainty_at(fit.prob, P, N_ref, len(bodies) - 1)
    pos, ax = ("coil_centre_mm", "coil_axis_deg") if C is not None else \
        ("marker_origin_mm", "marker_axis_deg")
    unc = {pos: u["position_mm"], ax: u["axis_deg"],
           "target": u["target"], "target_note": f"the session's mean {names[-1]} pose"}
    dist = {"model": fit.prob.model, "matrix": D, "undistort": G,
            "scale_percent": float((np.cbrt(np.linalg.det(D)) - 1.0) * 100.0),
            "axis_scale_percent": (np.diag(D) - 1.0) * 100.0,
            "tool_moments": dict(zip(names, moments, strict=True))}
    cal = Calibration("ml", len(A), X=Ws[0], Z=Z, X_raw=Ws[0].copy(), Z_raw=Z @ G4,
                      applied=Applied.ORTHONORMAL if orthonormal else Applied.RAW,
                      covariance=P, uncertainty=unc, distortion=dist)
    if C is not None:
        cal.Y, cal.Y_raw = Ws[1], Ws[1].copy()
    cal.extra = {"parameters": parameter_names(len(bodies), fit.prob.model),
                 "start": start.method, "iterations": fit.iterations, "chi2": fit.chi2,
                 "residuals": fit.m, "variance_factor": float(vf),
                 "criterion": criterion, criterion: bics,
                 "noise": {"robot_sigma_mm": noise[0],
                           "robot_sigma_deg": float(np.degrees(noise[1])),
                           "tracker": "spreads" if spreads is not None else
                           ("tracker_cov" if tracker_cov is not None else "sigmas"),
                           "scale_covariance": bool(scale_covariance)}}
    return cal
