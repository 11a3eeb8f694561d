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

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import CalibrationError
from ..geometry import invert, make_pose, orthonormalize
from . import Applied, Calibration, register_method, solve

__all__ = ["DISTORTION_MODELS", "ml_solve", "noise_covariance", "Problem", "undistort",
           "fit_model", "parameter_names", "tool_moment"]

#: distortion model → number of parameters
DISTORTION_MODELS = {"none": 0, "scale": 1, "axis": 3, "affine": 6}
_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # affine: symmetric G
STEPS = (1e-6, 1e-4)  # finite-difference steps: rotation (rad), translation (mm)
G_STEP = 1e-7


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """Rotation matrix exp([w]×) of one rotation vector w (rad)."""
    th = float(np.sqrt(w @ w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th ** 2 * K @ K


def _log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3) of rotations (n, 3, 3) near the identity (angle well below π:
    residuals), by θ = atan2(sin θ, cos θ) from the skew part and the trace."""
    w = 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0],
                        R[:, 1, 0] - R[:, 0, 1]], axis=1)
    s = np.linalg.norm(w, axis=1)
    th = np.arctan2(s, 0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0))
    f = np.where(s < 1e-12, 1.0, th / np.where(s < 1e-12, 1.0, s))
    return w * f[:, None]


def undistortion(model: str, g: np.ndarray) -> np.ndarray:
    """G = D⁻¹ (3×3) from the model's parameters g."""
    if model == "none":
        return np.eye(3)
    if model == "scale":
        return (1.0 + g[0]) * np.eye(3)
    if model == "axis":
        return np.diag(1.0 + g)
    G = np.eye(3)
    for v, (i, j) in zip(g, _SYM, strict=True):
        G[i, j] += v
        if i != j:
            G[j, i] += v
    return G


def tool_moment(tool_mm: Any) -> np.ndarray:
    """Second moment Σ q qᵀ (3×3, normalised) of a tool's fiducials (k, 3) mm about their
    centroid."""
    q = np.asarray(tool_mm, dtype=float)
    if q.ndim != 2 or q.shape[1] != 3 or len(q) < 3 or not np.all(np.isfinite(q)):
        raise CalibrationError("method 'ml': tools_mm must be (k ≥ 3, 3) fiducial positions, mm")
    q = q - q.mean(axis=0)
    M = q.T @ q
    return M / np.trace(M)


def undistort(N: np.ndarray, G: np.ndarray, model: str, M: np.ndarray | None = None
              ) -> np.ndarray:
    """Tracker poses N (n, 4, 4) with the distortion undone. The tracker fits each tool
    rigidly to distorted fiducials, so it reports t = D t₀ and R = polar(D R₀ M) (M the tool's
    second moment, :func:`tool_moment`); this returns G t and polar(G R M), which is R₀ to
    first order in D − I (exactly for the isotropic scale, where R is left alone). Without M
    (tool unknown) M = I, i.e. polar(G) R."""
    if model == "none":
        return N
    out = N.copy()
    out[:, :3, 3] = N[:, :3, 3] @ G.T
    if model != "scale":
        out[:, :3, :3] = (orthonormalize(G) @ N[:, :3, :3] if M is None else
                          orthonormalize(G[None] @ N[:, :3, :3] @ M))
    return out


@dataclass
class Problem:
    """One ML problem: poses A (n, 4, 4), bodies [B, (C)], start transforms Ws [X0, (Y0)],
    Z0, and the distortion model."""

    A: np.ndarray
    bodies: list[np.ndarray]
    Ws: list[np.ndarray]
    Z0: np.ndarray
    model: str = "none"
    g0: np.ndarray | None = None
    moments: list[np.ndarray | None] | None = None

    @property
    def n_params(self) -> int:
        return 6 * (len(self.Ws) + 1) + DISTORTION_MODELS[self.model]

    def unpack(self, th: np.ndarray) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """(Ws, Z, G) at parameters th (offsets from the start)."""
        def pose(T0: np.ndarray, p: np.ndarray) -> np.ndarray:
            return make_pose(T0[:3, :3] @ _rodrigues(p[:3]), T0[:3, 3] + p[3:])
        m = len(self.Ws)
        Ws = [pose(W, th[6 * j:6 * j + 6]) for j, W in enumerate(self.Ws)]
        Z = pose(self.Z0, th[6 * m:6 * m + 6])
        g = th[6 * m + 6:] if self.g0 is None else self.g0 + th[6 * m + 6:]
        return Ws, Z, undistortion(self.model, g)

    def residuals(self, th: np.ndarray) -> np.ndarray:
        """Raw residuals (n, 6m): per body [rotation vector (rad), translation (mm)]."""
        Ws, Z, G = self.unpack(th)
        out = []
        Ms = self.moments or [None] * len(Ws)
        for W, N, M in zip(Ws, self.bodies, Ms, strict=True):
            E = invert(self.A @ W) @ (Z @ undistort(N, G, self.model, M))
            out.append(np.concatenate([_log_so3(E[:, :3, :3]), E[:, :3, 3]], axis=1))
        return np.concatenate(out, axis=1)

    def jacobian(self, th: np.ndarray, whiten: np.ndarray) -> np.ndarray:
        """Whitened Jacobian (n·6m, k) by central differences."""
        cols = []
        for j in range(len(th)):
            h = G_STEP if j >= 6 * (len(self.Ws) + 1) else STEPS[(j % 6) // 3]
            e = np.zeros_like(th)
            e[j] = h
            d = (self.residuals(th + e) - self.residuals(th - e)) / (2 * h)
            cols.append(_apply(whiten, d).ravel())
        return np.stack(cols, axis=1)


def _apply(whiten: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Whiten residuals r (n, q) with L⁻¹ (q, q) or per pose (n, q, q)."""
    if whiten.ndim == 2:
        return r @ whiten.T
    return np.einsum("nij,nj->ni", whiten, r)


def _check_sigma(name: str, v: Any) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise CalibrationError(f"method 'ml': option {name} must be a number, got {v!r}") from None
    if not np.isfinite(f) or f <= 0:
        raise CalibrationError(f"method 'ml': option {name} must be finite and > 0, got {v!r}")
    return f


def _tracker_covs(n: int, names: list[str], opts: dict[str, Any]) -> np.ndarray:
    """Tracker covariance per pose and body (n, m, 6, 6), body frame [rot rad; trans mm]."""
    m = len(names)
    if opts.get("spreads") is not None:
        sp = list(opts["spreads"])
        if len(sp) != n:
            raise CalibrationError(f"method 'ml': spreads has {len(sp)} entries for {n} poses")
        out = np.zeros((n, m, 6, 6))
        for i, rec in enumerate(sp):
            spread = rec.get("spread", rec)
            samples = rec.get("samples", {})
            for j, (nm, key) in enumerate(zip(names, ("B", "C"), strict=False)):
                s = spread.get(nm) or {}
                k = max(1.0, float(samples.get(key, 1)))
                st = max(float(s.get("trans_mm", 0.0)), 1e-4) / np.sqrt(3 * k)
                sr = max(np.radians(float(s.get("rot_deg", 0.0))), 1e-6) / np.sqrt(3 * k)
                out[i, j] = np.diag([sr * sr] * 3 + [st * st] * 3)
        return out
    if opts.get("tracker_cov") is not None:
        cov = np.asarray(opts["tracker_cov"], dtype=float)
        if cov.shape != (6, 6) or not np.all(np.isfinite(cov)) or \
                np.linalg.eigvalsh((cov + cov.T) / 2)[0] <= 0:
            raise CalibrationError("method 'ml': tracker_cov must be a finite positive-definite "
                                   "6×6 matrix (body frame, [rot rad; trans mm])")
    else:
        st = _check_sigma("tracker_sigma_mm", opts["tracker_sigma_mm"])
        sr = np.radians(_check_sigma("tracker_sigma_deg", opts["tracker_sigma_deg"]))
        cov = np.diag([sr * sr] * 3 + [st * st] * 3)
    return np.broadcast_to(cov, (n, m, 6, 6))


def noise_covariance(Ws: list[np.ndarray], robot_sigma_mm: float, robot_sigma_rad: float,
                     tracker: np.ndarray) -> np.ndarray:
    """Residual covariance per pose (n, 6m, 6m): the robot's error δ (shared by the bodies of
    a pose) carried through each W, plus the tracker's (n, m, 6, 6) on the diagonal blocks."""
    m = len(Ws)
    J = np.zeros((6 * m, 6))
    for j, W in enumerate(Ws):
        R, t = W[:3, :3], W[:3, 3]
        tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
        J[6 * j:6 * j + 3, :3] = R.T
        J[6 * j + 3:6 * j + 6, :3] = -R.T @ tx
        J[6 * j + 3:6 * j + 6, 3:] = R.T
    Sd = np.diag([robot_sigma_rad ** 2] * 3 + [robot_sigma_mm ** 2] * 3)
    S = np.repeat((J @ Sd @ J.T)[None], len(tracker), axis=0)
    for j in range(m):
        S[:, 6 * j:6 * j + 6, 6 * j:6 * j + 6] += tracker[:, j]
    return S


def _whitener(S: np.ndarray) -> np.ndarray:
    """L⁻¹ per pose for S = L Lᵀ (collapsed to one matrix when all poses share S)."""
    if np.all(S == S[0]):
        return np.linalg.inv(np.linalg.cholesky(S[0]))
    return np.linalg.inv(np.linalg.cholesky(S))


def levenberg_marquardt(prob: Problem, whiten: np.ndarray, th: np.ndarray,
                        max_iter: int = 50) -> tuple[np.ndarray, np.ndarray, int]:
    """Minimise the whitened χ²; returns (θ, whitened Jacobian at θ, iterations)."""
    r = _apply(whiten, prob.residuals(th)).ravel()
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
            r_new = _apply(whiten, prob.residuals(new)).ravel()
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


def covariance_from_jacobian(J: np.ndarray, what: str) -> np.ndarray:
    """(JᵀJ)⁻¹ through column scaling; CalibrationError when J is rank deficient."""
    d = np.linalg.norm(J, axis=0)
    d[d == 0] = 1.0
    Js = J / d
    w, V = np.linalg.eigh(Js.T @ Js)  # columns scaled to unit norm: well conditioned
    if w[0] < 1e-14 * w[-1]:
        raise CalibrationError(f"{what} is not identifiable from these poses (the Jacobian is "
                               "rank deficient): use more poses with more rotation and "
                               "translation diversity, or a simpler distortion model")
    return (V / w) @ V.T / np.outer(d, d)


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
        whiten = _whitener(noise_covariance(Ws_now, noise[0], noise[1], noise[2]))
        th, _, it = levenberg_marquardt(prob, whiten, np.zeros(prob.n_params), max_iter)
        its += it
        Ws_new, Z, G = prob.unpack(th)
        prob = Problem(A, bodies, Ws_new, Z, model, _g_of(model, G), moments)
    th0 = np.zeros(prob.n_params)
    J = prob.jacobian(th0, whiten)
    P = covariance_from_jacobian(J, f"the ml model (distortion {model!r})")
    r = _apply(whiten, prob.residuals(th0)).ravel()
    return Fit(prob, J, P, float(r @ r), m, its)


def _g_of(model: str, G: np.ndarray) -> np.ndarray:
    """The parameters g of an undistortion G (inverse of :func:`undistortion`)."""
    if model == "none":
        return np.zeros(0)
    if model == "scale":
        return np.array([G[0, 0] - 1.0])
    if model == "axis":
        return np.diag(G) - 1.0
    return np.array([G[i, j] - (i == j) for i, j in _SYM])


def parameter_names(bodies: int, model: str) -> list[str]:
    """Names (with units) of the parameters, in the covariance's order."""
    names = []
    for T in ["X", "Y"][:bodies] + ["Z"]:
        names += [f"{T}.r{a} (rad)" for a in "xyz"] + [f"{T}.t{a} (mm)" for a in "xyz"]
    k = DISTORTION_MODELS[model]
    if model == "scale":
        names.append("G.s (1)")
    elif k:
        names += [f"G.{i} (1)" for i in (("xx", "yy", "zz") if model == "axis" else
                                          ("xx", "yy", "zz", "xy", "xz", "yz"))]
    return names


def _noise(n: int, names: list[str], opts: dict[str, Any]
           ) -> tuple[float, float, np.ndarray]:
    rs_mm = _check_sigma("robot_sigma_mm", opts["robot_sigma_mm"])
    rs_rad = np.radians(_check_sigma("robot_sigma_deg", opts["robot_sigma_deg"]))
    return rs_mm, rs_rad, _tracker_covs(n, names, opts)


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
             max_iter: int = 50) -> Calibration:
    """Maximum-likelihood X, (Y,) Z with tracker distortion ``distortion`` ("auto" by BIC,
    "none", "scale", "axis", "affine"); see the module docstring for the model, the noise
    options and the parameters. The raw matrices carry the distortion (Z_raw = Z · G, G =
    D⁻¹), as QR24's absorb it; ``errors`` undoes it either way."""
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
    from .bound import uncertainty_at
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
