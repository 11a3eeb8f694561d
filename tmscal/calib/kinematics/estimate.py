"""Maximum-likelihood hand/eye X, coil Y, robot/world Z and the arm's kinematic deviations
in one problem, from the tracker poses of a session whose robot joints were recorded
(docs/kinematics.md).

Frames and units as everywhere: A = base_from_flange, B = tracker_from_marker, C =
tracker_from_probe, X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker;
4×4, mm; joints rad.

Model. The flange sits where the TRUE arm puts the recorded joints, A_i = A(q_i; p0 + δ):
the nominal :class:`~tmscal.calib.kinematics.model.Arm` p0 plus deviations δ of its DH
parameters and Hayati angles (base_from_flange), up to the robot's repeatability (a small
rigid error per pose, as in :mod:`tmscal.calib.ml`); the tracker reports each body with its
noise. Per pose and body the residual is r = [log R(E) rad; t(E) mm] of
E = (A_i W)⁻¹ Z N_i (W = X or Y, N = B or C), whitened by the robot's and the tracker's noise
exactly as ``ml`` whitens it. Each deviation has a Gaussian prior N(0, τ²) — its
manufacturing tolerance — so that a few dozen poses do not overfit, and the estimate
minimises

    Σ_i r_iᵀ S_i⁻¹ r_i + Σ_j (δ_j / τ_j)²

by Levenberg–Marquardt with the analytic Jacobian (the deviations' body twists,
:func:`tmscal.calib.kinematics.jacobian.deviation_twists`, carried through E). The minimiser is
unique whatever the geometry: a direction of δ that the data cannot see (e.g. a base height
that Z absorbs, or d_2 − d_3 on parallel axes) costs prior and buys nothing, so it stays at
zero — the estimate lives in the identifiable subspace and has minimum norm (in tolerance
units) elsewhere, and it does not depend on the order or choice of equivalent parameters.

Identifiability (:mod:`tmscal.calib.kinematics.identifiability`): the data Jacobian of δ
with X, Y, Z projected out (the information about the arm that hand/eye and robot/world
cannot absorb), columns in tolerance units, by its singular value decomposition. A
singular value σ_k ≥ 1 means the poses know that combination better than the tolerance
does (identified: its estimate and posterior σ are reported); 0 < σ_k < 1 weakly identified
(the prior decides); σ_k ≈ 0 not identifiable, with the reason: the combination moves no
flange, or X/Y and/or Z absorb it.

Levels (:data:`LEVELS`): "none" (X, Y, Z on the nominal arm), "offsets" (joint zero
offsets θ0_i) and "full" (every θ0, d, a, α, and β where consecutive axes are parallel);
``level="auto"`` chooses by k-fold held-out χ², with the information criterion (AIC) as a
tie-break only within one standard error (:mod:`.levels`). The robot's noise is estimated
inside the fit by default (:mod:`.noise`).

Wrench rows (:mod:`tmscal.calib.kinematics.wrench`): where every pose has a wrist wrench, its
gravity wrench joins the sum as 6 whitened rows per pose, with 15 parameters of its own and no
prior (base tilt, sensor rotation, tool weight and centre of gravity, sensor bias), the
deviations reaching them through the arm's rotation; their noise is given (the recorded
spreads), so for the noise estimate they are rows of known variance, as the prior's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...errors import CalibrationError
from ...geometry import make_pose, matrix_from_rotvec
from ..lsq import levenberg_marquardt
from ..ml_model import (
    DISTORTION_MODELS,
    G_STEP,
    body_residual,
    g_of,
    noise_covariance,
    tracker_covs,
    undistort,
    undistortion,
    whitener,
)
from . import wrench as wm
from .identifiability import Combination, identifiability
from .jacobian import deviation_twists
from .levels import LEVELS, Tolerances, choose_level, level_parameters, prior_sigmas
from .model import Arm, base_from_flange
from .noise import (
    components,
    estimated_components,
    log_det,
    noise_report,
    theta_of,
    with_factors,
)

__all__ = ["LEVELS", "Tolerances", "KinematicFit", "Combination", "level_parameters",
           "fit_kinematics", "identifiability", "estimate_kinematics", "prior_sigmas",
           "Progress"]

#: a long fit's progress: ``progress(done, total, what)`` with ``done`` of ``total`` fits
#: finished (each level on all poses, each of its cross-validation folds) and ``what`` the
#: one running, its Levenberg–Marquardt iteration and cost (e.g. "full, fold 2/5: LM
#: iteration 3, cost 1.2e+04"); called after each LM iteration and each fit
Progress = Callable[[int, int, str], None]

# --- residuals and their analytic Jacobian ---------------------------------------------------

@dataclass
class _State:
    """Current estimate: Ws [X, (Y)], Z, the deviations δ (of ``names``) and the tracker's
    undistortion parameters g (``ml``'s, of the problem's distortion model)."""

    Ws: list[np.ndarray]
    Z: np.ndarray
    delta: np.ndarray
    g: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: the wrench model's parameters (:mod:`.wrench`), with wrench rows
    w: wm.WrenchParams | None = None


class _Problem:
    """The whitened least-squares problem of one level (module docstring)."""

    def __init__(self, q: np.ndarray, bodies: list[np.ndarray], chain0: Arm,
                 names: list[str], tau: np.ndarray, whiten: np.ndarray,
                 distortion: str = "none", moments: list[np.ndarray | None] | None = None,
                 wrench: wm.WrenchData | None = None) -> None:
        self.q, self.bodies, self.chain0 = q, bodies, chain0
        self.names, self.tau, self.whiten = names, tau, whiten
        self.model, self.moments = distortion, moments or [None] * len(bodies)
        self.nb = len(bodies)
        #: Z's columns: none in a wrench-only problem (no tracker rows, nothing to register)
        self.n_z = 6 if self.nb else 0
        self.n_g = DISTORTION_MODELS[distortion]
        #: the wrench data (rows after the tracker's) and the first column of its parameters
        self.wrench, self.c_w = wrench, 6 * self.nb + self.n_z + self.n_g
        #: X, (Y,) Z, the distortion and the wrench model: the parameters without a prior
        self.n_xyz = self.c_w + (len(wm.WRENCH_NAMES) if wrench is not None else 0)

    @property
    def n_params(self) -> int:
        return self.n_xyz + len(self.names)

    def _measured(self, g: np.ndarray) -> list[np.ndarray]:
        """The tracker poses with the distortion of parameters g undone (``ml``'s model)."""
        if self.model == "none":
            return self.bodies
        G = undistortion(self.model, g)
        return [undistort(N, G, self.model, M) for N, M in zip(self.bodies, self.moments,
                                                               strict=True)]

    def chain(self, s: _State) -> Arm:
        return self.chain0.with_deviations(self.names, s.delta) if self.names else self.chain0

    def evaluate(self, s: _State, jac: bool = True
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """(whitened residuals incl. the prior rows (m,), Jacobian (m, P) or None).

        The Jacobian is whitened block by block as it is built: with L the whitener (q, q)
        of a pose's q = 6·bodies rows (shared or per pose) and L_b its columns of body b,
        the columns of W_b are L_b ∂r_b/∂W_b, Z's Σ_b L_b ∂r_b/∂Z, and the deviations'
        (Σ_b L_b ∂r_b/∂ξ) J_k: products of (q, 6) blocks, written into the one (m, P) array
        (no whitening of the wide matrix, no copy of it)."""
        n, nb, P = len(self.q), self.nb, self.n_params
        q = 6 * nb
        chain = self.chain(s)
        # the flange poses by the chain's product; the deviations' twists only with the
        # Jacobian (the damping's trial steps need none: half the evaluations)
        A = base_from_flange(chain, self.q)
        Jk = None if not jac else deviation_twists(chain, self.q, self.names)[1] \
            if self.names else np.zeros((n, 6, 0))
        R_A = A[:, :3, :3]
        res = np.zeros((n, q))
        m_w = 6 * n if self.wrench is not None and s.w is not None else 0
        J = np.zeros((n * q + m_w + len(self.names), P)) if jac else None
        Jt = None if J is None else J[:n * q].reshape(n, q, P)   # a view: the tracker's rows
        K = np.zeros((n, q, 6)) if jac and self.names else None  # Σ_b L_b ∂r_b/∂ξ
        zc = slice(6 * nb, 6 * nb + 6)
        for b, (W, N) in enumerate(zip(s.Ws, self._measured(s.g), strict=True)):
            br = body_residual(A, W, s.Z, N, Jt is not None, flange=K is not None)
            rows = slice(6 * b, 6 * b + 6)
            res[:, rows] = br.r
            if Jt is None:
                continue
            assert br.dW is not None and br.dZ is not None
            Lb = self.whiten[..., :, rows]                      # (q, 6) or (n, q, 6)
            Jt[:, :, rows] = Lb @ br.dW
            Jt[:, :, zc] += Lb @ br.dZ
            if K is not None and br.dA is not None:  # the arm: A' = A exp(ξ), ξ = Jk δ
                K += Lb @ br.dA
        if Jt is not None and K is not None and Jk is not None:
            Jt[:, :, self.n_xyz:] = K @ Jk
        if Jt is not None and self.n_g:  # the distortion's few columns by central differences
            c0 = 6 * nb + self.n_z
            for k in range(self.n_g):
                e = np.zeros(self.n_g)
                e[k] = G_STEP
                rp = self._raw(_State(s.Ws, s.Z, s.delta, s.g + e), A)
                rm = self._raw(_State(s.Ws, s.Z, s.delta, s.g - e), A)
                Jt[:, :, c0 + k] = _apply(self.whiten, (rp - rm) / (2 * G_STEP))
        rw = _apply(self.whiten, res).ravel()
        prior = s.delta / self.tau
        if m_w:
            assert self.wrench is not None and s.w is not None
            wr, Jwr = wm.wrench_block(s.w, self.wrench, R_A, Jk, self.c_w, self.n_xyz, P,
                                      J is not None)
        else:
            wr, Jwr = np.zeros(0), None
        r = np.concatenate([rw, wr, prior])
        if J is None:
            return r, None
        if Jwr is not None:
            J[n * q:n * q + m_w] = Jwr
        k = len(self.names)
        J[n * q + m_w:, self.n_xyz:] = np.diag(1.0 / self.tau) if k else 0.0
        return r, J

    def _raw(self, s: _State, A: np.ndarray) -> np.ndarray:
        """Unwhitened residuals (n, 6·bodies) at the flange poses A."""
        return np.concatenate([body_residual(A, W, s.Z, N, False).r
                               for W, N in zip(s.Ws, self._measured(s.g), strict=True)], axis=1)

    def step(self, s: _State, d: np.ndarray) -> _State:
        """The state moved by parameters d (rotation vectors on the right, offsets in mm)."""
        def pose(T: np.ndarray, p: np.ndarray) -> np.ndarray:
            return make_pose(T[:3, :3] @ matrix_from_rotvec(p[:3]), T[:3, 3] + p[3:])
        Ws = [pose(W, d[6 * j:6 * j + 6]) for j, W in enumerate(s.Ws)]
        Z = pose(s.Z, d[6 * self.nb:6 * self.nb + 6]) if self.n_z else s.Z
        c0 = 6 * self.nb + self.n_z
        w = None if s.w is None else s.w.step(d[self.c_w:self.n_xyz])
        return _State(Ws, Z, s.delta + d[self.n_xyz:], s.g + d[c0:c0 + self.n_g], w)


def _apply(whiten: np.ndarray, r: np.ndarray) -> np.ndarray:
    return r @ whiten.T if whiten.ndim == 2 else np.einsum("nij,nj->ni", whiten, r)


def _levenberg_marquardt(prob: _Problem, s: _State, max_iter: int,
                         on_iteration: Callable[[int, float], None] | None = None
                         ) -> tuple[_State, np.ndarray, np.ndarray, int]:
    """Minimise the whitened cost from s with the one least-squares loop
    (:func:`tmscal.calib.lsq.levenberg_marquardt`; converged when the cost falls by less than
    1e-12 of itself); returns (state, residuals, Jacobian, iterations)."""
    sol = levenberg_marquardt(lambda st, jac: prob.evaluate(st, jac=jac), s, prob.step,
                              max_iter=max_iter, ftol=1e-12, on_iteration=on_iteration)
    assert sol.jacobian is not None
    return sol.state, sol.residuals, sol.jacobian, sol.iterations


# --- one level --------------------------------------------------------------------------------

@dataclass
class KinematicFit:
    """One fitted level: ``chain`` (the identified arm, an :class:`Arm`), ``names``/``delta``/``sd``
    (deviations in rad or mm and their posterior SDs), X, (Y,) Z (4×4 mm), ``chi2`` of the
    data rows, ``m`` residuals, ``p_eff`` effective parameters, ``variance_factor``
    χ²/(m − p_eff), ``covariance`` of [X, (Y,) Z, δ] (rows as ``ml``: rotation vector rad,
    offset mm, then δ), ``identified``/``weak``/``unidentified`` combinations, the
    information criterion ``aic``, LM ``iterations``, and the tracker ``distortion`` model
    with its undistortion ``G`` = D⁻¹ (3×3; identity for "none")."""

    level: str
    chain: Arm
    names: list[str]
    delta: np.ndarray
    sd: np.ndarray
    #: None in a wrench-only fit (no tracker rows: nothing registered)
    X: np.ndarray | None
    Y: np.ndarray | None
    Z: np.ndarray | None
    chi2: float
    m: int
    p_eff: float
    variance_factor: float
    covariance: np.ndarray
    identified: list[Combination] = field(default_factory=list)
    weak: list[Combination] = field(default_factory=list)
    unidentified: list[Combination] = field(default_factory=list)
    aic: float = float("nan")
    iterations: int = 0
    #: the tracker distortion model estimated with the rest and its undistortion G (3×3)
    distortion: str = "none"
    G: np.ndarray = field(default_factory=lambda: np.eye(3))
    #: with wrench rows: :func:`.wrench.wrench_report` of the wrench model; None without
    wrench: dict[str, Any] | None = None
    #: the noise the fit was weighted with (``ml``'s option dictionary; estimated or as
    #: given) and its report (:func:`tmscal.calib.kinematics.noise.noise_report`)
    noise_used: dict[str, Any] = field(default_factory=dict)
    noise: dict[str, Any] = field(default_factory=dict)


#: rounds of noise estimate → refit at most, and the relative change of every noise factor
#: below which they stop
NOISE_ROUNDS = 6
NOISE_TOL = 0.01


def _whitener_for(Ws: list[np.ndarray], noise: dict[str, Any], n: int) -> np.ndarray:
    if not Ws:  # a wrench-only problem: no tracker rows to whiten
        return np.eye(0)
    names = ["marker", "probe"][:len(Ws)]
    tracker = tracker_covs(n, names, noise)
    rs_mm = float(noise["robot_sigma_mm"])
    rs_rad = float(np.radians(noise["robot_sigma_deg"]))
    return whitener(noise_covariance(Ws, rs_mm, rs_rad, tracker))


def fit_kinematics(q: np.ndarray, bodies: list[np.ndarray], chain0: Arm, level: str,
                   start: tuple[list[np.ndarray], np.ndarray], noise: dict[str, Any],
                   tol: Tolerances = Tolerances(), max_iter: int = 50,
                   distortion: str = "none",
                   moments: list[np.ndarray | None] | None = None,
                   wrench: wm.WrenchData | None = None,
                   noise_mode: str = "estimate", *, warm: KinematicFit | None = None,
                   identify: bool = True,
                   on_iteration: Callable[[int, float], None] | None = None
                   ) -> KinematicFit:
    """Fit one level from ``start`` = ([X0, (Y0)], Z0); ``noise`` holds ``ml``'s noise
    options (robot_sigma_mm, robot_sigma_deg, tracker_sigma_mm/deg, tracker_cov or
    spreads); ``distortion`` a tracker distortion model of ``ml`` ("none", "scale", "axis",
    "affine") estimated with the rest, ``moments`` the tools' second moments (``ml``'s
    ``tool_moment``; None: isotropic). ``wrench``: the wrench rows' data (:mod:`.wrench`),
    one per pose, or None.

    ``noise_mode`` "given": the whitening is evaluated at the start and once more at the
    estimate, the covariance scaled by the variance factor. "estimate" (default, as
    ``ml``): after the fit with the given noise, the robot's rotation and translation noise
    (and the tracker's level without spreads or tracker_cov) are estimated by REML from the
    tracker's rows at the estimate, the wrench's and the prior's as rows of known variance
    (:mod:`tmscal.calib.kinematics.noise`), and the fit is repeated with them, until no
    factor changes by more than :data:`NOISE_TOL` (at most :data:`NOISE_ROUNDS` rounds); the
    covariance is then that of the estimated noise, unscaled, and the information criterion
    includes the noise's log-determinant (the likelihood with the noise estimated).

    ``warm``: a fit of the same level, distortion and rows (e.g. on all poses, for a fold of
    them) whose X, Y, Z, δ, distortion and wrench model start the iteration instead of
    ``start`` and zero deviations: the same minimum in fewer iterations. ``identify`` False
    leaves the identifiability analysis out (``identified``, ``weak``, ``unidentified``
    empty; a cross-validation fold needs only the estimate). ``on_iteration(it, cost)``: called
    after each Levenberg–Marquardt iteration (:func:`tmscal.calib.lsq.levenberg_marquardt`)."""
    if not bodies:  # the force-sensor self-calibration: wrench rows only (no X, Y, Z)
        if wrench is None:
            raise CalibrationError("kinematics: no tracker poses and no wrenches: nothing "
                                   "to fit the arm to")
        if distortion != "none":
            raise CalibrationError("kinematics: a tracker distortion needs tracker poses")
        noise_mode = "given"   # the wrench's σ are given; no tracker rows to estimate from
    flags = estimated_components(noise, noise_mode)
    if distortion not in DISTORTION_MODELS:
        raise CalibrationError(f"kinematics: unknown distortion {distortion!r}; expected "
                               f"{', '.join(DISTORTION_MODELS)}")
    names = level_parameters(chain0, level)
    tau = prior_sigmas(names, tol)
    s = _State([W.copy() for W in start[0]], start[1].copy(), np.zeros(len(names)),
               np.zeros(DISTORTION_MODELS[distortion]),
               None if wrench is None
               else wm.initial_wrench(wrench, base_from_flange(chain0, q)[:, :3, :3])) \
        if warm is None else _warm_state(warm, names, distortion, wrench is not None)
    its, cur, comp, rounds = 0, noise, None, 0
    m_t = len(q) * 6 * len(bodies)                      # the tracker's rows
    m = len(q) * 6 * (len(bodies) + (wrench is not None))  # every data row
    for _ in range(1 if flags.any() else 2):
        whiten = _whitener_for(s.Ws, cur, len(q))
        prob = _Problem(q, bodies, chain0, names, tau, whiten, distortion, moments, wrench)
        s, r, J, it = _levenberg_marquardt(prob, s, max_iter, on_iteration)
        its += it
    if flags.any():  # the noise from the residuals, then the fit with it, until it settles
        raw = _Problem(q, bodies, chain0, names, tau, np.eye(6 * len(bodies)), distortion,
                       moments, wrench)
        while rounds < NOISE_ROUNDS:
            rounds += 1
            comp = components(*raw.evaluate(s), m_t, s.Ws, cur, flags, noise)
            done = bool(np.all(np.abs(comp.theta / theta_of(cur) - 1.0) <= NOISE_TOL))
            cur = with_factors(cur, comp.theta)
            whiten = _whitener_for(s.Ws, cur, len(q))
            prob = _Problem(q, bodies, chain0, names, tau, whiten, distortion, moments, wrench)
            s, r, J, it = _levenberg_marquardt(prob, s, max_iter, on_iteration)
            its += it
            if done:
                break
    data_r = r[:m]
    chi2 = float(data_r @ data_r)
    Jx = J[:m, :prob.c_w]
    sx = np.linalg.svd(Jx / np.maximum(np.linalg.norm(Jx, axis=0), 1e-300),
                       compute_uv=False) if prob.c_w else np.ones(1)
    if sx[-1] <= 1e-7 * sx[0]:
        raise CalibrationError("kinematics: hand/eye, coil and robot/world are not "
                               "identifiable from these poses: use more poses with more "
                               "rotation and translation diversity")
    H = J.T @ J                      # the prior rows make it positive definite
    d = np.sqrt(np.diag(H))
    d[d == 0] = 1.0
    w, V = np.linalg.eigh(H / np.outer(d, d))
    w = np.maximum(w, 1e-15 * w.max())  # rounding, not information: H is positive definite
    P = (V / w) @ V.T / np.outer(d, d)
    P = 0.5 * (P + P.T)              # symmetric to the last bit, as a file reader checks
    Jd = J[:m]
    p_eff = float(np.trace(P @ (Jd.T @ Jd)))
    vf = chi2 / max(m - p_eff, 1.0)
    sc = 1.0 if flags.any() else vf  # the covariance's scale: estimated noise as it is
    k = len(names)
    fit = KinematicFit(level, prob.chain(s), names, s.delta.copy(),
                       np.sqrt(np.diag(P)[prob.n_xyz:] * sc) if k else np.zeros(0),
                       s.Ws[0] if s.Ws else None, s.Ws[1] if len(s.Ws) > 1 else None,
                       s.Z if s.Ws else None, chi2, m, p_eff, vf,
                       P * sc, iterations=its, distortion=distortion,
                       G=undistortion(distortion, s.g), noise_used=cur,
                       noise=noise_report(noise_mode, noise, cur, comp, rounds) if bodies
                       else {"mode": "given", "rows": "wrench only", "scale_covariance": True})
    if flags.any():  # −2 ln L with the noise estimated (ml's profiled form when given)
        fit.aic = chi2 + log_det(whiten, len(q)) + 2.0 * p_eff
    else:
        fit.aic = m * float(np.log(max(chi2 / m, 1e-300))) + 2.0 * p_eff
    if s.w is not None:
        fit.wrench = wm.wrench_report(s.w, np.sqrt(np.diag(P)[prob.c_w:prob.n_xyz] * sc),
                                   r[m - 6 * len(q):m])
    if k and identify:
        fit.identified, fit.weak, fit.unidentified = identifiability(
            prob.names, prob.tau, s.delta, Jd, prob.n_xyz, prob.nb, bool(prob.n_g), sc,
            None if wrench is None else prob.c_w)
    return fit


def _warm_state(fit: KinematicFit, names: list[str], distortion: str, wrench: bool) -> _State:
    """The state of a fit (:func:`fit_kinematics`' ``warm``), checked to be of the same
    problem."""
    if fit.names != names or fit.distortion != distortion or (fit.wrench is None) == wrench:
        raise CalibrationError("kinematics: a warm start needs a fit of the same level, "
                               "distortion and rows")
    Ws = [W.copy() for W in (fit.X, fit.Y) if W is not None]
    Z = np.eye(4) if fit.Z is None else fit.Z.copy()
    return _State(Ws, Z, fit.delta.copy(), g_of(distortion, fit.G),
                  None if fit.wrench is None else fit.wrench["params"])


# --- level selection --------------------------------------------------------------------------

@dataclass
class KinematicsResult:
    """The chosen fit, the fits of every level tried (``fits``), and the held-out table
    ``cv``: {level: {"e_t_mm": mean over folds, "se_mm": its standard error, "folds": k}}
    (None for a level fitted without cross-validation), and ``reason`` for the choice."""

    fit: KinematicFit
    fits: dict[str, KinematicFit]
    cv: dict[str, dict[str, float] | None]
    reason: str


def _heldout_e_t(fit: KinematicFit, q: np.ndarray, bodies: list[np.ndarray],
                 moments: list[np.ndarray | None] | None = None) -> np.ndarray:
    """Per pose e_t (mm): the sum over bodies of ‖t((A W)⁻¹ Z N)‖ with A from the fitted arm
    (N undistorted by the fitted distortion)."""
    A = base_from_flange(fit.chain, q)
    Ws = [fit.X] if fit.Y is None else [fit.X, fit.Y]
    e = np.zeros(len(q))
    Ms = moments or [None] * len(bodies)
    if fit.distortion != "none":
        bodies = [undistort(N, fit.G, fit.distortion, M) for N, M in zip(bodies, Ms,
                                                                         strict=True)]
    for W, N in zip(Ws, bodies, strict=True):
        E = np.linalg.inv(A @ W) @ (fit.Z @ N)
        e += np.linalg.norm(E[:, :3, 3], axis=1)
    return e


def _heldout_chi2(fit: KinematicFit, q: np.ndarray, bodies: list[np.ndarray], chain0: Arm,
                  noise: dict[str, Any], moments: list[np.ndarray | None] | None
                  ) -> np.ndarray:
    """Per pose the χ² of the tracker poses' residuals under the fit, whitened by ``noise``
    (:mod:`.levels`)."""
    Ws = [fit.X] if fit.Y is None else [fit.X, fit.Y]
    whiten = _whitener_for(Ws, noise, len(q))
    prob = _Problem(q, bodies, chain0, fit.names, np.ones(len(fit.names)), whiten,
                    fit.distortion, moments)
    r, _ = prob.evaluate(_State(Ws, fit.Z, fit.delta, g_of(fit.distortion, fit.G)), jac=False)
    r = r[:len(q) * 6 * len(bodies)].reshape(len(q), -1)
    return np.sum(r * r, axis=1)


def _folds(n: int, k: int) -> list[np.ndarray]:
    idx = np.arange(n)
    return [idx[idx % k == f] for f in range(k)]


def _subset_noise(noise: dict[str, Any], keep: np.ndarray) -> dict[str, Any]:
    if noise.get("spreads") is None:
        return noise
    sp = list(noise["spreads"])
    return {**noise, "spreads": [sp[i] for i in keep]}


def estimate_kinematics(q: np.ndarray, bodies: list[np.ndarray], chain0: Arm,
                        start: tuple[list[np.ndarray], np.ndarray], noise: dict[str, Any],
                        level: str = "auto", tol: Tolerances = Tolerances(), folds: int = 5,
                        max_iter: int = 50, distortion: str = "none",
                        moments: list[np.ndarray | None] | None = None,
                        wrench: wm.WrenchData | None = None,
                        noise_mode: str = "estimate",
                        progress: Progress | None = None) -> KinematicsResult:
    """Fit the level asked for, or with ``level="auto"`` every level of :data:`LEVELS` and
    keep the one with the lowest k-fold held-out χ² per pose (``folds`` interleaved folds;
    X, Y, Z and δ refitted on each training part; every level's held-out residuals whitened
    by the same noise, the richest level's; :mod:`.levels` says why and how ties are broken).
    ``distortion``, ``moments``, ``wrench`` and ``noise_mode`` as :func:`fit_kinematics`,
    the same for every level (the held-out χ² is the tracker's). With the noise estimated,
    each level's cross-validation fits take the noise that level estimated on all poses as
    given (the rig's noise does not change between folds; a REML per fold would cost k more
    noise loops per level and estimate two or three numbers from 4/5 of the poses, the same
    numbers less well). Each fold's fit starts from its level's fit on all poses (the same
    minimum in a few iterations) and leaves out the identifiability analysis, which only the
    fits on all poses report.

    ``progress`` (:data:`Progress`): called as the fits go (1 with a level given, else one
    per level and one per level and fold), e.g. for a progress bar."""
    opts: dict[str, Any] = {"distortion": distortion, "moments": moments}
    n = len(q)
    k = max(2, min(folds, n // 4))
    total = 1 if level != "auto" else len(LEVELS) * (1 + k)
    done = 0

    def report(what: str) -> Callable[[int, float], None] | None:
        if progress is None:
            return None
        progress(done, total, what)
        return lambda it, cost: progress(done, total, f"{what}: LM iteration {it}, cost "
                                                      f"{cost:.4g}")

    def finished(what: str) -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total, f"{what}: done")

    if level != "auto":
        fit = fit_kinematics(q, bodies, chain0, level, start, noise, tol, max_iter, **opts,
                             wrench=wrench, noise_mode=noise_mode,
                             on_iteration=report(f"{level}, all {n} poses"))
        finished(f"{level}, all {n} poses")
        return KinematicsResult(fit, {level: fit}, {level: None}, f"level {level} as asked")
    fits = {}
    for lv in LEVELS:
        fits[lv] = fit_kinematics(q, bodies, chain0, lv, start, noise, tol, max_iter, **opts,
                                  wrench=wrench, noise_mode=noise_mode,
                                  on_iteration=report(f"{lv}, all {n} poses"))
        finished(f"{lv}, all {n} poses")
    weights = fits[LEVELS[-1]].noise_used  # the noise least inflated by the arm's error
    heldout = {}
    for lv in LEVELS:
        scores: list[tuple[np.ndarray, np.ndarray]] = []
        for j, test in enumerate(_folds(n, k)):
            train = np.setdiff1d(np.arange(n), test)
            what = f"{lv}, fold {j + 1}/{k}"
            try:
                f = fit_kinematics(q[train], [N[train] for N in bodies], chain0, lv, start,
                                   _subset_noise(fits[lv].noise_used, train), tol, max_iter,
                                   **opts, noise_mode="given",
                                   wrench=None if wrench is None else wrench.subset(train),
                                   warm=fits[lv], identify=False, on_iteration=report(what))
            except CalibrationError:
                done += k - j - 1   # the level's other folds are not fitted
                finished(f"{what}: not identifiable")
                scores = []
                break
            finished(what)
            held = [N[test] for N in bodies]
            scores.append((_heldout_e_t(f, q[test], held, moments),
                           _heldout_chi2(f, q[test], held, chain0,
                                         _subset_noise(weights, test), moments)))
        heldout[lv] = tuple(np.concatenate(x) for x in zip(*scores)) if scores else None
    best, reason, cv = choose_level(heldout, {lv: f.aic for lv, f in fits.items()}, k)
    if best is None:
        raise CalibrationError(f"kinematics: too few poses ({n}) to cross-validate the levels")
    return KinematicsResult(fits[best], fits, cv, reason)
