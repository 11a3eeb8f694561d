"""What moved since a calibration, and the re-registration of only that (docs/lab-day.md).

A stored calibration (X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker;
4×4 mm) is held against a new session's poses (A = base_from_flange, B = tracker_from_marker,
C = tracker_from_probe). Each pose and body gives the residual E = (A X)⁻¹ Z N, written as
six numbers r = [t(E) mm; rotation vector of E in degrees]; the calibration's **noise model**
(:class:`NoiseModel`, the covariance Σ of r over the poses it was solved on) whitens them.

The hypotheses, each one rigid change Δ = [R(ω) v; 0 1] (v mm, ω a rotation vector) or, for
the arm, joint offsets δ (rad), fitted by maximum likelihood (whitened least squares,
Levenberg–Marquardt from a closed-form start) with everything else fixed:

======================  ========  =======================================================
hypothesis              block     model
======================  ========  =======================================================
``tracker`` moved       ``z``     Z' = Z Δ (Δ in the tracker's frame; every pose, both bodies)
``coil`` re-seated      ``coil``  X' = Δ X, Y' = Δ Y (one flange-frame Δ for both bodies)
``marker`` moved        ``x``     X' = X Δ (the marker on the coil; the probe untouched)
``coil_centre`` changed ``y``     Y' = Y Δ (e.g. another coil; the marker untouched)
``arm`` changed         ``arm``   A' = fk(q + δ) (only where joints and an arm model are known)
======================  ========  =======================================================

The decision (:func:`diagnose`): each hypothesis is nested in "nothing changed", so each is
tested against it with the F test of the extra sum of squares (the scale of the noise
estimated from today's residuals, so that a noisier or quieter day than the calibration's
does not pass for a change; Bonferroni over the hypotheses, family level ``ALPHA``). Among the
significant ones the winner has the smallest AICc, Akaike's criterion with the small-sample
correction of Hurvich & Tsai (1989) — 10 poses of 12 numbers and 6 parameters are few enough
that the plain AIC would favour larger models; hypotheses of equal size are then ranked by
their likelihood alone. The runner-up's evidence ratio is exp(ΔAICc / 2). "unexplained" when
the winner leaves residuals beyond ``ALLOWANCE``× the stored noise (χ², 99.9 %) or a second
change on top of it is significant (the pair is named). :func:`update` fits only the named
blocks and refuses (:class:`UpdateRefused`) when either holds, so that an update never
absorbs a second change silently.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import chi2
from scipy.stats import f as f_dist

from ..errors import CalibrationError
from ..geometry import make_pose, matrix_from_rotvec, orthonormalize, pose_mean, rotvec_from_matrix
from .calibration import Applied, Calibration

__all__ = ["HYPOTHESES", "BLOCK_OF", "UPDATES", "ALPHA", "ALLOWANCE", "CHI2_LEVEL",
           "NoiseModel", "Frames", "frames", "residuals", "noise_from_residuals",
           "noise_from_errors", "calibration_noise", "Fit", "fit", "Diagnosis", "diagnose",
           "UpdateRefused", "HYPOTHESIS_OF", "COMPONENTS", "blocks_of_update", "min_poses",
           "update", "updated", "noise_after", "placement_spread", "suggested_tolerances",
           "pose_covariance"]

#: the changes told apart, in the order a tie is broken (the commonest first)
HYPOTHESES = ("tracker", "coil", "marker", "coil_centre", "arm")
#: the block of parameters each hypothesis frees
BLOCK_OF = {"tracker": "z", "coil": "coil", "marker": "x", "coil_centre": "y", "arm": "arm"}
HYPOTHESIS_OF = {b: h for h, b in BLOCK_OF.items()}
#: ``--update`` names → the hypothesis they re-register
UPDATES = {"z": "tracker", "x": "marker", "y": "coil_centre", "coil": "coil"}
#: family-wise false-alarm level of the tests (a change claimed on an unchanged rig)
ALPHA = 0.01
#: today's noise may be this many times the calibration's before the residuals count as
#: unexplained (a tracker warming up, another room's lighting)
ALLOWANCE = 3.0
#: the χ² quantile of that adequacy test
CHI2_LEVEL = 0.999
COMPONENTS = ("tx_mm", "ty_mm", "tz_mm", "rx_deg", "ry_deg", "rz_deg")
#: relative singular value below which a fit's parameters count as undetermined
RANK_TOL = 1e-7


@dataclass(frozen=True)
class NoiseModel:
    """The covariance of the residual r = [t(E) mm; rotation vector deg] of each body, bodies
    stacked in ``bodies`` order ((6·len(bodies))² mm/deg), with where it came from
    (``source``) and how many poses it was estimated on (``n_poses``)."""

    cov: np.ndarray
    bodies: tuple[str, ...]
    source: str = "residuals"
    n_poses: int = 0
    #: the calibration's own uncertainty: the covariance of small changes of its blocks
    #: (``cal_blocks``, e.g. ("z", "x", "y"); 6-vectors [v mm; ω rad] as :class:`Fit`'s)
    #: on the poses it was solved on. Every held-out residual shares this error, so the
    #: tests whiten with it (generalised least squares); None when unknown
    cal_cov: np.ndarray | None = None
    cal_blocks: tuple[str, ...] = ()

    def for_bodies(self, bodies: Sequence[str]) -> NoiseModel:
        """The model restricted to ``bodies`` (a marker-only session of a two-body
        calibration). CalibrationError for a body the model does not have."""
        idx: list[int] = []
        for b in bodies:
            if b not in self.bodies:
                raise CalibrationError(f"the noise model has no {b!r} body (it has "
                                       f"{', '.join(self.bodies)})")
            i = self.bodies.index(b)
            idx += list(range(6 * i, 6 * i + 6))
        return replace(self, cov=self.cov[np.ix_(idx, idx)], bodies=tuple(bodies))

    def calibration_for(self, fr: Frames) -> tuple[tuple[str, ...], np.ndarray] | None:
        """(blocks, covariance) of the calibration's uncertainty that bear on ``fr``'s
        bodies (y only with the probe), or None when unknown."""
        if self.cal_cov is None or not self.cal_blocks:
            return None
        keep, idx, i0 = [], [], 0
        for b in self.cal_blocks:
            if b != "y" or "probe" in fr.N:
                keep.append(b)
                idx += list(range(i0, i0 + 6))
            i0 += 6
        return tuple(keep), self.cal_cov[np.ix_(idx, idx)]

    def sigmas(self) -> dict[str, dict[str, float]]:
        """Per body the RMS of the translation (mm per axis) and rotation (deg per axis)."""
        d = np.sqrt(np.diag(self.cov))
        return {b: {"mm": float(np.sqrt(np.mean(d[6 * i:6 * i + 3] ** 2))),
                    "deg": float(np.sqrt(np.mean(d[6 * i + 3:6 * i + 6] ** 2)))}
                for i, b in enumerate(self.bodies)}

    def to_json(self) -> dict[str, Any]:
        """Plain types, as the calibration file's ``noise_model`` holds it."""
        out: dict[str, Any] = {"bodies": list(self.bodies), "components": list(COMPONENTS),
                               "covariance": self.cov.tolist(), "poses": int(self.n_poses),
                               "source": self.source}
        if self.cal_cov is not None:
            out["calibration"] = {"blocks": list(self.cal_blocks),
                                  "covariance": self.cal_cov.tolist(),
                                  "units": "per block [v mm (3), ω rad (3)]"}
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> NoiseModel:
        """The inverse of :meth:`to_json` (values already checked by the file's reader)."""
        c = d.get("calibration") or {}
        return cls(np.asarray(d["covariance"], dtype=float), tuple(d["bodies"]),
                   str(d.get("source", "residuals")), int(d.get("poses", 0)),
                   None if not c else np.asarray(c["covariance"], dtype=float),
                   tuple(c.get("blocks", ())))


@dataclass
class Frames:
    """A session's poses as a calibration applies them: ``A`` (n, 4, 4) base_from_flange mm,
    per body (``"marker"``, ``"probe"``) the tracker poses ``N``, the flange_from_body ``X``
    and the base_from_tracker ``Z`` (4×4 mm, as applied: raw or orthonormal, a tracker
    distortion undone); the joints (n, dof) rad and ``fk`` (joints → A in the same frame)
    when the arm hypothesis can be tested; ``indices``: session pose indices."""

    A: np.ndarray
    N: dict[str, np.ndarray]
    X: dict[str, np.ndarray]
    Z: dict[str, np.ndarray]
    joints: np.ndarray | None = None
    fk: Callable[[np.ndarray], np.ndarray] | None = None
    indices: list[int] | None = None
    #: the point (flange frame, mm) a coil re-seat turns about: the coil's centre (the
    #: marker's origin without the probe), so that its Δ's translation is the centre's move
    centre: np.ndarray | None = None
    #: the whitening of the stacked residuals, computed once by :func:`fit`
    whiten: Callable[[np.ndarray], np.ndarray] | None = field(default=None, repr=False)

    @property
    def bodies(self) -> tuple[str, ...]:
        return tuple(self.N)

    @property
    def n(self) -> int:
        return len(self.A)


def frames(cal: Calibration, A: np.ndarray, B: np.ndarray, C: np.ndarray | None = None,
           joints: np.ndarray | None = None,
           fk: Callable[[np.ndarray], np.ndarray] | None = None,
           indices: list[int] | None = None) -> Frames:
    """The :class:`Frames` of poses A, B, C (n, 4, 4) mm under ``cal``: its orthonormal
    matrices (``Calibration.holdout_frames`` as if applied orthonormal: a tracker
    distortion undone), whichever set it applies — the changes told apart are rigid, and
    the raw linear solution's small non-rigid error would grow with a large move (a tracker
    250 mm away from where it was calibrated); C ignored for a marker-only calibration."""
    rigid = replace(cal, applied=Applied.ORTHONORMAL)
    B, C, u = rigid.holdout_frames(np.asarray(B, float),
                                   None if C is None else np.asarray(C, float))
    N = {"marker": B}
    X = {"marker": u["X"]}
    Z = {"marker": u["Z"]}
    if C is not None and u["Y"] is not None:
        N["probe"] = C
        X["probe"] = u["Y"]
        Z["probe"] = u["Z_probe"] if u["Z_probe"] is not None else u["Z"]
    c = (X["probe"] if "probe" in X else X["marker"])[:3, 3].copy()
    return Frames(np.asarray(A, float), N, X, Z, joints, fk, indices, c)


def _residual(A: np.ndarray, X: np.ndarray, Z: np.ndarray, N: np.ndarray) -> np.ndarray:
    E = orthonormalize(np.linalg.inv(A @ X) @ (Z @ N))
    return np.concatenate([E[:, :3, 3], np.degrees(rotvec_from_matrix(E))], axis=1)


def residuals(fr: Frames) -> np.ndarray:
    """(n, 6·bodies) residuals [t(E) mm; rotation vector deg] of every pose, bodies in
    ``fr.bodies`` order, E = (A X)⁻¹ Z N."""
    return np.concatenate([_residual(fr.A, fr.X[b], fr.Z[b], fr.N[b]) for b in fr.bodies],
                          axis=1)


def noise_from_residuals(r: np.ndarray, bodies: Sequence[str], fitted: int,
                         source: str = "residuals") -> NoiseModel:
    """The noise model from in-sample residuals r (n, q) of a calibration that fitted
    ``fitted`` parameters to them: Σ = Σᵢ rᵢ rᵢᵀ / (n − fitted/q) (each parameter uses up a
    q-th of a pose), shrunk toward its diagonal by λ = min(1, q/n) so that it is positive
    definite on few poses."""
    r = np.asarray(r, dtype=float)
    n, q = r.shape
    if n < 2:
        raise CalibrationError(f"a noise model needs at least 2 poses, got {n}")
    S = r.T @ r / max(n - fitted / q, 1.0)
    lam = min(1.0, q / n)
    S = (1 - lam) * S + lam * np.diag(np.diag(S))
    floor = 1e-12 + 1e-9 * float(np.max(np.diag(S)))
    S = S + floor * np.eye(q)
    return NoiseModel(S, tuple(bodies), source, n)


#: closed-form methods whose own sampling error :func:`calibration_noise` measures by a
#: parametric bootstrap (cheap to re-solve); others use the likelihood's covariance
BOOTSTRAP_METHODS = ("qr36", "qr24")
BOOTSTRAP_REPS = 60


def calibration_noise(cal: Calibration, A: np.ndarray, B: np.ndarray,
                      C: np.ndarray | None = None, source: str = "residuals",
                      seed: int = 0) -> NoiseModel:
    """The noise model of a calibration from the poses it was solved on (A, B, C: (n, 4, 4)
    mm): the residual covariance (:func:`noise_from_residuals`, 6 parameters per solved
    transform) and the calibration's own uncertainty (:attr:`NoiseModel.cal_cov`, blocks z,
    x (y)): for QR24/QR36 a parametric bootstrap — the poses' tracker readings perturbed by
    draws of that residual noise, re-solved ``BOOTSTRAP_REPS`` times by the same method, the
    covariance of the re-solved blocks — since these linear solvers are less efficient than
    the likelihood and the likelihood's covariance understates their error; for other
    methods the likelihood's, (JᵀJ)⁻¹ of the whitened Jacobian on these poses."""
    fr = frames(cal, A, B, C)
    bodies = fr.bodies
    nm = noise_from_residuals(residuals(fr), bodies, 6 * (len(bodies) + 1), source)
    blocks = ("z", "x", "y") if "probe" in bodies else ("z", "x")
    if cal.method in BOOTSTRAP_METHODS and cal.distortion is None and cal.arm is None:
        cov = _bootstrap(cal, A, B, C if "probe" in bodies else None, nm, blocks, seed)
        if cov is not None:
            return replace(nm, cal_cov=cov, cal_blocks=blocks)
    ft = fit(fr, nm, blocks)
    if not ft.rank_ok or not np.all(np.isfinite(ft.cov)):
        return nm
    return replace(nm, cal_cov=ft.cov, cal_blocks=blocks)


def _bootstrap(cal: Calibration, A: np.ndarray, B: np.ndarray, C: np.ndarray | None,
               nm: NoiseModel, blocks: tuple[str, ...], seed: int) -> np.ndarray | None:
    from .methods import solve

    rng = np.random.default_rng(seed)
    n = len(A)
    ref = {"z": cal.Z, "x": cal.X, "y": cal.Y}
    draws = []
    q6 = len(nm.cov)
    Km = np.linalg.cholesky(nm.cov[:6, :6] / 2)
    Kh = np.linalg.cholesky(nm.cov / 2)
    for _ in range(BOOTSTRAP_REPS):
        # half the residual variance as the robot's (in the flange frame, shared by both
        # bodies: errors in A bias a linear solver, errors in N do not), half the tracker's
        f = rng.standard_normal((n, 6)) @ Km.T
        F = np.stack([cal.X @ make_pose(matrix_from_rotvec(np.radians(f[j, 3:])), f[j, :3])
                      @ np.linalg.inv(cal.X) for j in range(n)])
        e = rng.standard_normal((n, q6)) @ Kh.T
        bodies = [B] + ([] if C is None else [C])
        pert = []
        for i, N in enumerate(bodies):
            d = e[:, 6 * i:6 * i + 6]
            D = np.stack([make_pose(matrix_from_rotvec(np.radians(d[j, 3:])), d[j, :3])
                          for j in range(n)])
            pert.append(N @ D)
        A_p = A @ F
        try:
            c2 = solve(A_p, pert[0], pert[1] if C is not None else None, method=cal.method,
                       orthonormal=cal.applied == Applied.ORTHONORMAL)
        except (CalibrationError, np.linalg.LinAlgError, ValueError):
            return None
        new = {"z": c2.Z, "x": c2.X, "y": c2.Y}
        draws.append(np.concatenate([_xi(np.linalg.inv(ref[b]) @ new[b]) for b in blocks]))
    X = np.asarray(draws)
    S = np.cov(X, rowvar=False)
    S = (S + S.T) / 2 + 1e-12 * np.eye(len(S))
    return S if np.all(np.isfinite(S)) else None


#: E‖t‖ of an isotropic 3-D Gaussian of σ per axis is 2·√(2/π)·σ
_MEAN_NORM = 2 * np.sqrt(2 / np.pi)


def noise_from_errors(errors: dict[str, Any], bodies: Sequence[str]) -> NoiseModel:
    """An isotropic noise model from a calibration's stored mean errors (files written
    before the noise model was stored): per body σ = trans_mm / (2√(2/π)) per axis, and
    likewise in degrees. CalibrationError when the errors have no figure for a body."""
    d = []
    for b in bodies:
        e = errors.get(b) if isinstance(errors, dict) else None
        if not isinstance(e, dict) or not {"trans_mm", "rot_deg"} <= set(e):
            if isinstance(errors, dict) and len(bodies) == 1 and "e_t_mm" in errors:
                e = {"trans_mm": errors["e_t_mm"], "rot_deg": errors["theta_t_deg"]}
            else:
                raise CalibrationError(f"the calibration's stored errors give no {b!r} "
                                       "figures, from which a noise model could come")
        st = max(float(e["trans_mm"]), 1e-6) / _MEAN_NORM
        sr = max(float(e["rot_deg"]), 1e-6) / _MEAN_NORM
        d += [st] * 3 + [sr] * 3
    return NoiseModel(np.diag(np.square(d)), tuple(bodies), "stored errors (isotropic)", 0)


def _cal_jacobian(fr: Frames, blocks: Sequence[str]) -> np.ndarray:
    """d(stacked residuals)/d(calibration blocks' 6-vectors) at zero, (m, 6·blocks)."""
    r0 = residuals(fr).ravel()
    cols = []
    h = 1e-6
    for b in blocks:
        for j in range(6):
            p = {bb: np.zeros(6) for bb in blocks}
            p[b][j] = h
            cols.append((residuals(_apply(fr, blocks, p)).ravel() - r0) / h)
    return np.stack(cols, axis=1)


def pose_covariance(fr: Frames, noise: NoiseModel) -> np.ndarray:
    """(n, q, q) the covariance of each pose's residual r (mm and deg, bodies in
    ``fr.bodies`` order) on an unchanged rig: the noise model's Σ of each pose plus the
    calibration's own error at that pose, J_i C_c J_iᵀ (J_i the pose's rows of the
    residuals' Jacobian with respect to the calibration's blocks; without C_c, Σ alone).
    The live monitor's S of a hold (``calib.alarm``)."""
    Sp = noise.for_bodies(fr.bodies).cov
    q = len(Sp)
    out = np.repeat(Sp[None], fr.n, axis=0)
    cc = noise.calibration_for(fr)
    if cc is None:
        return out
    blocks, C = cc
    J = _cal_jacobian(replace(fr, whiten=None), blocks).reshape(fr.n, q, -1)
    return out + np.einsum("nij,jk,nlk->nil", J, C, J)


def _anchor(fr: Frames, noise: NoiseModel, candidates: Sequence[tuple[str, ...]]) -> None:
    """Fix ``fr``'s whitening at the frames of the best of ``candidates`` (block tuples, ()
    = nothing changed) fitted with each pose's noise alone: the calibration's error enters
    through the residuals' Jacobian, which must be taken near the solution (a tracker
    turned by 30° turns it too). One whitening for every model then compared."""
    if noise.cal_cov is None:
        return
    plain = replace(noise, cal_cov=None, cal_blocks=())
    f0 = replace(fr, whiten=None)
    best = None
    for c in candidates:
        ft = fit(f0, plain, c)
        if ft.rank_ok and (best is None or ft.aicc < best.aicc):
            best = ft
    at = best.frames if best is not None else fr
    fr.whiten = _whitening(replace(at, whiten=None), noise)


def _whitening(fr: Frames, noise: NoiseModel) -> Callable[[np.ndarray], np.ndarray]:
    """w(r) ~ N(0, I) for the residuals r (n, q) of an unchanged rig, stacked pose-major:
    Cov r = I ⊗ Σ + J_c C_c J_cᵀ, the noise of each pose and the calibration's own error
    (C_c, through the residuals' Jacobian J_c with respect to its blocks) that all poses
    share; without C_c each pose is whitened by Σ alone. Cached on ``fr``."""
    if fr.whiten is not None:
        return fr.whiten
    Sp = noise.for_bodies(fr.bodies).cov
    cc = noise.calibration_for(fr)
    if cc is None:
        Wp = np.linalg.inv(np.linalg.cholesky(Sp))
        fr.whiten = lambda r: (r @ Wp.T).ravel()
        return fr.whiten
    blocks, C = cc
    J = _cal_jacobian(fr, blocks)
    S = np.kron(np.eye(fr.n), Sp) + J @ C @ J.T
    W = np.linalg.solve(np.linalg.cholesky(S), np.eye(len(S)))
    fr.whiten = lambda r: W @ r.ravel()
    return fr.whiten


def _delta(xi: np.ndarray) -> np.ndarray:
    return make_pose(matrix_from_rotvec(xi[3:]), xi[:3])


def _xi(D: np.ndarray) -> np.ndarray:
    return np.concatenate([D[:3, 3], rotvec_from_matrix(D[:3, :3])])


def _size(block: str, fr: Frames) -> int:
    return len(fr.joints[0]) if block == "arm" else 6  # type: ignore[index]


def _about(fr: Frames) -> np.ndarray:
    return make_pose(None, np.zeros(3) if fr.centre is None else fr.centre)


def _coil_delta(fr: Frames, p: np.ndarray) -> np.ndarray:
    """A coil re-seat's flange-frame Δ: ξ turns about and shifts the coil's centre."""
    T = _about(fr)
    return T @ _delta(p) @ np.linalg.inv(T)


def _moved(fr: Frames, deltas: dict[str, np.ndarray], A: np.ndarray | None = None) -> Frames:
    """The frames with rigid block changes (4×4 mm Δ by block) applied: Z' = Z Δ (z),
    X' = X Δ (x), Y' = Y Δ (y), X' = Δ X and Y' = Δ Y (coil); ``A`` replaces the robot poses
    (the arm's)."""
    X, Z = dict(fr.X), dict(fr.Z)
    for b, D in deltas.items():
        if b == "z":
            Z = {k: v @ D for k, v in Z.items()}
        elif b == "x":
            X["marker"] = X["marker"] @ D
        elif b == "y":
            X["probe"] = X["probe"] @ D
        elif b == "coil":
            X = {k: D @ v for k, v in X.items()}
    return Frames(fr.A if A is None else A, fr.N, X, Z, fr.joints, fr.fk, fr.indices,
                  fr.centre)


def _apply(fr: Frames, blocks: Sequence[str], params: dict[str, np.ndarray]) -> Frames:
    A = None
    deltas = {}
    for b in blocks:
        p = params[b]
        if b == "arm":
            A = fr.fk(fr.joints + p)  # type: ignore[misc,operator]
        else:
            deltas[b] = _coil_delta(fr, p) if b == "coil" else _delta(p)
    return _moved(fr, deltas, A)


def _start(fr: Frames, block: str) -> np.ndarray:
    """A closed-form start: the mean over poses of the Δ that makes each pose exact."""
    if block == "arm":
        return np.zeros(_size(block, fr))
    b = "probe" if block == "y" else "marker"
    A, X, Z, N = fr.A, fr.X[b], fr.Z[b], fr.N[b]
    inv = np.linalg.inv
    if block == "z":
        D = inv(Z) @ A @ X @ inv(N)
    elif block in ("x", "y"):
        D = inv(X) @ inv(A) @ Z @ N
    else:  # coil, about the coil's centre
        T = _about(fr)
        D = inv(T) @ inv(A) @ Z @ N @ inv(X) @ T
    return _xi(pose_mean(orthonormalize(D)))


@dataclass
class Fit:
    """The maximum-likelihood fit of ``blocks`` (() = nothing changed) on some frames:
    ``params`` per block (6-vectors [v mm; ω rad] of Δ, or joint offsets rad), their
    covariance ``cov`` (k×k, the blocks' order), ``rss`` (the whitened residual sum of
    squares), ``m`` numbers fitted by ``k`` parameters on ``n`` poses, ``rank_ok`` (the
    parameters are determined by these poses), ``frames`` (the fitted frames)."""

    blocks: tuple[str, ...]
    params: dict[str, np.ndarray]
    cov: np.ndarray
    rss: float
    m: int
    k: int
    n: int
    rank_ok: bool
    frames: Frames = field(repr=False)

    @property
    def dof(self) -> int:
        return self.m - self.k

    @property
    def noise_ratio(self) -> float:
        """The RMS whitened residual: 1 when today's residuals are as the stored noise."""
        return float(np.sqrt(self.rss / max(self.dof, 1)))

    @property
    def aicc(self) -> float:
        """AICc (Hurvich & Tsai 1989) with the noise scale estimated: K = k + 1."""
        K = self.k + 1
        m = self.m
        return float(m * np.log(max(self.rss, 1e-300) / m) + 2 * K
                     + 2 * K * (K + 1) / max(m - K - 1, 1))

    def delta(self, block: str) -> np.ndarray:
        """Δ of a rigid block (4×4 mm): Z' = Z Δ, X' = X Δ, Y' = Y Δ, coil X' = Δ X."""
        p = self.params[block]
        return _coil_delta(self.frames, p) if block == "coil" else _delta(p)

    def size(self, block: str) -> dict[str, float]:
        """{"mm", "deg", "sigma_mm", "sigma_deg"} of a rigid block's Δ (‖v‖, the rotation
        angle, and their σ by the delta method), or for the arm the largest joint offset
        in degrees ("deg", "sigma_deg", "joint")."""
        i0 = 0
        for b in self.blocks:
            if b == block:
                break
            i0 += _size(b, self.frames)
        p = self.params[block]
        C = self.cov[i0:i0 + len(p), i0:i0 + len(p)]
        if block == "arm":
            j = int(np.argmax(np.abs(p)))
            return {"deg": float(np.degrees(abs(p[j]))),
                    "sigma_deg": float(np.degrees(np.sqrt(max(C[j, j], 0.0)))),
                    "joint": j + 1, "mm": float("nan"), "sigma_mm": float("nan")}

        def norm_sd(v: np.ndarray, S: np.ndarray) -> tuple[float, float]:
            s = float(np.linalg.norm(v))
            g = v / s if s > 0 else np.ones(3) / np.sqrt(3)
            return s, float(np.sqrt(max(g @ S @ g, 0.0)))

        mm, smm = norm_sd(p[:3], C[:3, :3])
        rad, srad = norm_sd(p[3:], C[3:, 3:])
        return {"mm": mm, "deg": float(np.degrees(rad)), "sigma_mm": smm,
                "sigma_deg": float(np.degrees(srad))}


def fit(fr: Frames, noise: NoiseModel, blocks: Sequence[str] = ()) -> Fit:
    """Maximum likelihood of ``blocks`` on frames ``fr`` with the noise model (restricted to
    the frames' bodies), everything else fixed. The covariance is (JᵀJ)⁻¹ of the whitened
    Jacobian scaled by max(1, s²) (today's noise when it is larger than the stored)."""
    blocks = tuple(blocks)
    for b in blocks:
        if b == "arm" and (fr.fk is None or fr.joints is None):
            raise CalibrationError("the arm hypothesis needs the joints and an arm model")
        if b == "y" and "probe" not in fr.N:
            raise CalibrationError("the coil centre (Y) needs the probe's poses")
    W = _whitening(fr, noise)
    q = 6 * len(fr.bodies)
    sizes = [_size(b, fr) for b in blocks]
    cuts = np.cumsum([0] + sizes)

    def unpack(p: np.ndarray) -> dict[str, np.ndarray]:
        return {b: p[cuts[i]:cuts[i + 1]] for i, b in enumerate(blocks)}

    def fun(p: np.ndarray) -> np.ndarray:
        return W(residuals(_apply(fr, blocks, unpack(p))))

    m = fr.n * q
    if not blocks:
        f0 = fun(np.zeros(0))
        return Fit((), {}, np.zeros((0, 0)), float(f0 @ f0), m, 0, fr.n, True, fr)
    # sequential closed-form starts: each block on the frames the earlier ones fixed
    x0: list[np.ndarray] = []
    cur = fr
    for b in blocks:
        s = _start(cur, b)
        x0.append(s)
        cur = _apply(cur, (b,), {b: s})
    p0 = np.concatenate(x0)
    k = len(p0)
    res = least_squares(fun, p0, method="lm" if m >= k else "trf", x_scale="jac",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200 * (k + 1))
    J = res.jac
    sv = np.linalg.svd(J, compute_uv=False) if J.size else np.zeros(0)
    rank_ok = bool(m >= k and len(sv) == k and sv[-1] > RANK_TOL * max(sv[0], 1e-300))
    rss = float(res.fun @ res.fun)
    s2 = rss / (m - k) if m > k else 1.0
    try:
        cov = np.linalg.pinv(J.T @ J) * max(1.0, s2)
        cov = (cov + cov.T) / 2
    except np.linalg.LinAlgError:
        cov = np.full((k, k), np.inf)
    params = unpack(res.x)
    return Fit(blocks, params, cov, rss, m, k, fr.n, rank_ok, _apply(fr, blocks, params))


def _f_p(small: Fit, big: Fit) -> float:
    """p-value of the F test of the extra sum of squares, ``big`` nesting ``small``."""
    dk = big.k - small.k
    if big.dof <= 0 or dk <= 0:
        return 1.0
    floor = 1e-10 * big.m  # whitened units: far below any noise, above rounding
    if small.rss <= floor:
        return 1.0  # nothing left to explain
    if big.rss <= floor:
        return 0.0  # the larger model explains what is left exactly
    F = max(small.rss - big.rss, 0.0) / dk / (big.rss / big.dof)
    return float(f_dist.sf(F, dk, big.dof))


def _beyond_noise(ft: Fit, allowance: float) -> bool:
    """The residuals beyond ``allowance``× the stored noise (χ² at CHI2_LEVEL)."""
    return ft.dof > 0 and ft.rss > allowance ** 2 * chi2.ppf(CHI2_LEVEL, ft.dof)


def _hypotheses(fr: Frames) -> list[str]:
    """The hypotheses these frames can test: with the probe all four rigid ones; marker
    only, the tracker and the coil (a marker moved on the coil and a coil re-seated are the
    same X change without the probe); the arm where joints and an arm model are known."""
    hs = ["tracker", "coil"] + (["marker", "coil_centre"] if "probe" in fr.N else [])
    if fr.fk is not None and fr.joints is not None:
        hs.append("arm")
    return hs


def _overlap(a: str, b: str) -> bool:
    return {a, b} in ({"coil", "x"}, {"coil", "y"}) or a == b


@dataclass
class Diagnosis:
    """What :func:`diagnose` decided: ``changed`` (``none``, a hypothesis, or
    ``unexplained``), the fits by hypothesis (``fits``, "none" included), their p-values
    against nothing changed, the ``pair`` of changes a second test found, notes."""

    changed: str
    fits: dict[str, Fit]
    p_values: dict[str, float]
    winner: str | None
    runner_up: str | None
    evidence_ratio: float | None
    pair: tuple[str, str] | None = None
    notes: list[str] = field(default_factory=list)
    alpha: float = ALPHA
    allowance: float = ALLOWANCE

    @property
    def label(self) -> str:
        """A phrase: "the tracker moved", "nothing changed", …"""
        return {"none": "nothing changed", "tracker": "the tracker moved",
                "coil": "the coil was re-seated on the flange",
                "marker": "the marker moved on the coil",
                "coil_centre": "the coil's centre changed (another coil?)",
                "arm": "the arm changed (a joint offset)",
                "unexplained": "none of the single changes explains the session"
                }[self.changed]

    def to_json(self) -> dict[str, Any]:
        """The ``diagnosis`` object of ``--json`` (mm, degrees)."""
        main = self.winner if self.winner in self.fits else None
        size = self.fits[main].size(BLOCK_OF[main]) if main and main != "none" else None
        alts = []
        for h, ft in sorted(self.fits.items(), key=lambda kv: kv[1].aicc):
            a: dict[str, Any] = {"changed": h, "aicc": ft.aicc, "noise_ratio": ft.noise_ratio,
                                 "p_value": self.p_values.get(h)}
            if h != "none":
                s = ft.size(BLOCK_OF[h])
                a.update(delta_mm=_num(s["mm"]), delta_deg=_num(s["deg"]))
            alts.append(a)
        return {"changed": self.changed, "label": self.label,
                "winner": self.winner,
                "delta_mm": _num(size["mm"]) if size else None,
                "delta_deg": _num(size["deg"]) if size else None,
                "sigma": ({"mm": _num(size["sigma_mm"]), "deg": _num(size["sigma_deg"])}
                          if size else None),
                **({"joint": size["joint"]} if size and "joint" in size else {}),
                "runner_up": self.runner_up, "evidence_ratio": _num(self.evidence_ratio),
                "pair": list(self.pair) if self.pair else None,
                "noise_ratio": (self.fits[main].noise_ratio if main else
                                self.fits["none"].noise_ratio),
                "alternatives": alts, "notes": list(self.notes),
                "test": {"rule": "F test against nothing changed (Bonferroni), AICc "
                                 "(Hurvich & Tsai 1989) among the significant; docs/lab-day.md",
                         "alpha": self.alpha, "allowance": self.allowance,
                         "chi2_level": CHI2_LEVEL}}


def _num(x: float | None) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def diagnose(fr: Frames, noise: NoiseModel, alpha: float = ALPHA,
             allowance: float = ALLOWANCE) -> Diagnosis:
    """Which single change explains the session (module docstring; docs/lab-day.md)."""
    hs = _hypotheses(fr)
    _anchor(fr, noise, [()] + [(BLOCK_OF[h],) for h in hs])
    none = fit(fr, noise)
    fits = {"none": none}
    notes: list[str] = []
    if "probe" not in fr.N:
        notes.append("marker only: a marker moved on the coil and a coil re-seated on the "
                     "flange are one X change without the probe (both reported as 'coil')")
    for h in hs:
        ft = fit(fr, noise, (BLOCK_OF[h],))
        if ft.rank_ok and ft.dof > 0:
            fits[h] = ft
        else:
            notes.append(f"{h}: not determined by these {fr.n} poses")
    p = {h: _f_p(none, ft) for h, ft in fits.items() if h != "none"}
    level = alpha / max(len(p), 1)
    sig = [h for h in p if p[h] < level]
    tie = {h: i for i, h in enumerate(HYPOTHESES)}

    def order(h: str) -> tuple[float, float, int]:
        f = fits[h]
        return (round(f.aicc, 6), f.rss, tie.get(h, -1))

    if not sig:
        winner = "none"
        changed = "unexplained" if _beyond_noise(none, allowance) else "none"
        if changed == "unexplained":
            notes.append(f"the residuals are {none.noise_ratio:.1f}× the calibration's noise "
                         f"(allowance {allowance:g}×) and no single change explains them")
        rest = sorted((h for h in fits if h != "none"), key=order)
    else:
        ranked = sorted(sig, key=order)
        winner = ranked[0]
        changed = winner
        rest = [h for h in sorted(fits, key=order) if h != winner]
    runner = rest[0] if rest else None
    ev = (float(np.exp(min((fits[runner].aicc - fits[winner].aicc) / 2, 700)))
          if runner else None)
    pair = None
    if changed not in ("none", "unexplained"):
        best = fits[winner]
        wb = BLOCK_OF[winner]
        extras = [h for h in hs if h != winner and not _overlap(BLOCK_OF[h], wb)]
        pvals = {}
        for h in extras:
            two = fit(fr, noise, (wb, BLOCK_OF[h]))
            if two.rank_ok and two.dof > 0:
                pvals[h] = _f_p(best, two)
        if pvals:
            h2 = min(pvals, key=pvals.__getitem__)
            if pvals[h2] < alpha / len(pvals):
                pair = (winner, h2)
                changed = "unexplained"
                notes.append(f"a second change on top of '{winner}' is significant: "
                             f"'{h2}' (p = {pvals[h2]:.2g})")
        if changed != "unexplained" and _beyond_noise(best, allowance):
            changed = "unexplained"
            notes.append(f"after '{winner}' the residuals are still {best.noise_ratio:.1f}× "
                         f"the calibration's noise (allowance {allowance:g}×)")
    ratio = fits[winner].noise_ratio
    if changed not in ("unexplained",) and ratio > 1.5:
        notes.append(f"today's residuals are {ratio:.1f}× the calibration's noise")
    return Diagnosis(changed, fits, p, winner, runner, ev, pair, notes, alpha, allowance)


class UpdateRefused(CalibrationError):
    """An update that does not explain the session (a second change, or residuals beyond the
    noise model); ``diagnosis`` says what does, ``fit`` is the refused fit."""

    def __init__(self, message: str, diagnosis: Diagnosis | None = None,
                 fit: Fit | None = None) -> None:
        super().__init__(message)
        self.diagnosis = diagnosis
        self.fit = fit


def blocks_of_update(names: Sequence[str]) -> tuple[str, ...]:
    """The blocks of ``--update`` names (z, x, y, coil; repeatable: ``z`` with ``x`` or
    ``y`` or ``coil``, ``x`` with ``y``). CalibrationError for an unknown or repeated name,
    or ``coil`` with ``x`` or ``y`` (coil already frees X and Y together)."""
    out: list[str] = []
    for n in names:
        if n not in UPDATES:
            raise CalibrationError(f"--update {n!r}: expected one of "
                                   f"{', '.join(UPDATES)} (z: the tracker, x: the marker "
                                   "on the coil, y: the coil's centre, coil: X and Y "
                                   "together, the coil re-seated)")
        if n in out:
            raise CalibrationError(f"--update {n} given twice")
        out.append(n)
    if "coil" in out and ({"x", "y"} & set(out)):
        raise CalibrationError("--update coil frees X and Y together; leave out --update x "
                               "and --update y")
    if not out:
        raise CalibrationError("--update: name at least one of z, x, y, coil")
    return tuple(out)


def min_poses(blocks: Sequence[str], with_probe: bool) -> int:
    """The fewest poses with which an update of ``blocks`` AND its check for one more change
    are determined with degrees of freedom to spare: 3 whenever the tracker and the coil's
    mount can both be free (Z with a change of X, as in AX = ZB: two motions with
    non-parallel rotation axes, Tsai & Lenz 1989) — an update of z or coil, or any update
    of a marker-only session; 2 for x, y (each body's own offset on top of the other's
    fixed frame: one pose determines, the second leaves the check its redundancy)."""
    blocks = set(blocks)
    if not with_probe or blocks & {"z", "coil"}:
        return 3
    return 2


def update(fr: Frames, noise: NoiseModel, names: Sequence[str], alpha: float = ALPHA,
           allowance: float = ALLOWANCE) -> Fit:
    """Maximum likelihood of only the named blocks (``--update`` names, see
    :func:`blocks_of_update`), everything else fixed. CalibrationError when the session
    cannot determine the update or its check (too few poses, one orientation);
    :class:`UpdateRefused` when the update leaves residuals beyond ``allowance``× the noise
    model or a further change on top of it is significant (Bonferroni at ``alpha``)."""
    blocks = blocks_of_update(names)
    if "y" in blocks and "probe" not in fr.N:
        raise CalibrationError("--update y needs the probe's poses (the coil's centre); the "
                               "session has the marker only")
    need = min_poses(blocks, "probe" in fr.N)
    if fr.n < need:
        raise CalibrationError(
            f"--update {' '.join(blocks)} needs at least {need} usable poses"
            f"{'' if 'probe' in fr.N else ' of a marker-only session'}, the session has "
            f"{fr.n}: {need} is the fewest that determine the update and still leave the "
            "check for a second change its redundancy (docs/lab-day.md)")
    _anchor(fr, noise, [blocks])
    ft = fit(fr, noise, blocks)
    if not ft.rank_ok:
        raise CalibrationError(f"--update {' '.join(blocks)}: the session's {fr.n} poses do "
                               "not determine it (too little rotation between them?)")
    extras = [h for h in _hypotheses(fr)
              if not any(_overlap(BLOCK_OF[h], b) for b in blocks)
              and not (BLOCK_OF[h] == "coil" and "probe" not in fr.N and "x" in blocks)]
    pvals = {}
    for h in extras:
        two = fit(fr, noise, blocks + (BLOCK_OF[h],))
        if not (two.rank_ok and two.dof > 0):
            if h == "arm":
                continue  # said in the result's notes by the caller
            raise CalibrationError(
                f"--update {' '.join(blocks)}: these {fr.n} poses cannot tell it from a "
                f"further change of the {h.replace('_', ' ')} (one orientation, or too "
                "little rotation between the poses): record poses turned about at least "
                "two different axes (Tsai & Lenz 1989)")
        pvals[h] = _f_p(ft, two)
    why = None
    if pvals:
        h2 = min(pvals, key=pvals.__getitem__)
        if pvals[h2] < alpha / len(pvals):
            why = (f"a further change is significant on top of it: the "
                   f"{h2.replace('_', ' ')} (p = {pvals[h2]:.2g})")
    if why is None and _beyond_noise(ft, allowance):
        why = (f"the residuals after it are {ft.noise_ratio:.1f}× the calibration's noise "
               f"(allowance {allowance:g}×)")
    if why is not None:
        raise UpdateRefused(f"--update {' '.join(blocks)} does not explain the session: "
                            f"{why}; nothing was written", diagnose(fr, noise, alpha,
                                                                   allowance), ft)
    return ft


def updated(cal: Calibration, ft: Fit) -> Calibration:
    """The calibration with the fitted blocks applied (``ft`` from :func:`update` on frames
    of ``cal``): Z' = Z Δ (raw: through the tracker distortion, Z_raw D Δ D⁻¹), X' = X Δ,
    Y' = Y Δ, coil: X' = Δ X, Y' = Δ Y, raw and orthonormal alike; every other matrix, the
    distortion and the arm are the same objects. The solver's covariance and predicted
    uncertainty no longer apply and are dropped; the result applies the orthonormal matrices
    (the update was fitted on them, :func:`frames`)."""
    ch: dict[str, Any] = {}
    d = cal.distortion
    D4 = np.eye(4)
    if d is not None and d.get("matrix") is not None and d.get("model") != "none":
        D4[:3, :3] = np.asarray(d["matrix"], dtype=float)
    for b in ft.blocks:
        D = ft.delta(b)
        if b == "z":
            through = D4 @ D @ np.linalg.inv(D4)
            ch["Z"] = (ch.get("Z", cal.Z)) @ D
            ch["Z_raw"] = (ch.get("Z_raw", cal.Z_raw)) @ through
            if cal.Z_probe is not None:
                ch["Z_probe"] = cal.Z_probe @ D
            if cal.Z_probe_raw is not None:
                ch["Z_probe_raw"] = cal.Z_probe_raw @ through
        elif b == "x":
            ch["X"], ch["X_raw"] = cal.X @ D, cal.X_raw @ D
        elif b == "y":
            ch["Y"], ch["Y_raw"] = cal.Y @ D, cal.Y_raw @ D  # type: ignore[operator]
        elif b == "coil":
            ch["X"], ch["X_raw"] = D @ cal.X, D @ cal.X_raw
            if cal.Y is not None:
                ch["Y"], ch["Y_raw"] = D @ cal.Y, D @ cal.Y_raw  # type: ignore[operator]
    for k in ("X", "Y", "Z", "Z_probe"):
        if k in ch:
            ch[k] = orthonormalize(ch[k])  # rigid to rounding
    extra = dict(cal.extra, updated=list(ft.blocks))
    extra.pop("parameters", None)
    return replace(cal, **ch, covariance=None, uncertainty=None, extra=extra,
                   applied=Applied.ORTHONORMAL)


def noise_after(noise: NoiseModel, ft: Fit) -> NoiseModel:
    """The noise model of the updated calibration: the same residual covariance, and the
    calibration's own uncertainty grown by the update's (its covariance carried to the
    blocks z, x, y by the Jacobian of Z⁻¹Z', X⁻¹X', Y⁻¹Y' with respect to the fitted
    parameters), so that the next check does not mistake the update's own error for a
    change. Unchanged when the model has no calibration uncertainty."""
    if noise.cal_cov is None or not ft.blocks:
        return noise
    fr0 = _apply_blocks_only(ft)
    p0 = np.concatenate([ft.params[b] for b in ft.blocks])
    sizes = [len(ft.params[b]) for b in ft.blocks]
    cuts = np.cumsum([0] + sizes)
    inv = np.linalg.inv

    def cal_xi(p: np.ndarray) -> np.ndarray:
        f = _apply(fr0, ft.blocks, {b: p[cuts[i]:cuts[i + 1]]
                                    for i, b in enumerate(ft.blocks)})
        out = []
        for b in noise.cal_blocks:
            if b == "z":
                D = inv(ft.frames.Z["marker"]) @ f.Z["marker"]
            else:
                body = "marker" if b == "x" else "probe"
                if body not in f.X:
                    out.append(np.zeros(6))
                    continue
                D = inv(ft.frames.X[body]) @ f.X[body]
            out.append(_xi(orthonormalize(D)))
        return np.concatenate(out)

    h = 1e-6
    c0 = cal_xi(p0)
    G = np.stack([(cal_xi(p0 + h * e) - c0) / h for e in np.eye(len(p0))], axis=1)
    C = noise.cal_cov + G @ ft.cov @ G.T
    return replace(noise, cal_cov=(C + C.T) / 2,
                   source=f"{noise.source}, with the update of {' '.join(ft.blocks)} on "
                          f"{ft.n} poses")


def placement_spread(ft: Fit, samples: int = 400, seed: int = 0) -> dict[str, float] | None:
    """The predicted coil-placement error (mm) that the update's own uncertainty leaves:
    Monte Carlo of the fitted parameters (their covariance) through the flange command
    Z C Y⁻¹ at the session's coil poses (the probe's, or the marker's with X⁻¹ Y), the
    coil's distance from where the point estimate puts it; {"mean_mm", "p95_mm"}. The
    untouched transforms' own uncertainty is not included. None for a marker-only fit."""
    fr = ft.frames
    if "probe" not in fr.X or not ft.blocks or not np.all(np.isfinite(ft.cov)):
        return None
    rng = np.random.default_rng(seed)
    p = np.concatenate([ft.params[b] for b in ft.blocks])
    L = np.linalg.cholesky(ft.cov + 1e-18 * np.eye(len(p)))
    base = _apply_blocks_only(ft)
    Zh, Yh = fr.Z["probe"], fr.X["probe"]
    targets = fr.N["probe"]
    want = Zh @ targets  # the coil where the point estimate places it (base frame)
    errs = []
    sizes = [len(ft.params[b]) for b in ft.blocks]
    cuts = np.cumsum([0] + sizes)
    for _ in range(samples):
        s = p + L @ rng.standard_normal(len(p))
        fs = _apply(base, ft.blocks, {b: s[cuts[i]:cuts[i + 1]]
                                      for i, b in enumerate(ft.blocks)})
        F = fs.Z["probe"] @ targets @ np.linalg.inv(fs.X["probe"])  # commanded flange
        got = F @ Yh  # the coil with the point estimate's mount
        errs.append(np.linalg.norm(got[:, :3, 3] - want[:, :3, 3], axis=1))
    e = np.concatenate(errs)
    return {"mean_mm": float(e.mean()), "p95_mm": float(np.quantile(e, 0.95))}


def _apply_blocks_only(ft: Fit) -> Frames:
    """The frames before the fit (the fitted rigid blocks undone), for re-sampling."""
    return _moved(ft.frames, {b: np.linalg.inv(ft.delta(b)) for b in ft.blocks if b != "arm"})


def suggested_tolerances(noise: NoiseModel, n_poses: int, level: float = 0.99,
                         sessions: int = 4000, seed: int = 0,
                         fr: Frames | None = None,
                         stored: dict[str, Any] | None = None) -> dict[str, Any]:
    """Tolerances for the daily check's totals from the noise model: the ``level`` quantile
    of e_t (mm, the sum of the bodies' mean ‖t(E)‖) and θ_t (deg) over ``sessions``
    simulated unchanged sessions of ``n_poses`` poses: each pose's noise drawn from the
    model and, given the session's frames ``fr`` and a model with the calibration's own
    uncertainty, that error too (one draw per session, shared by its poses, through the
    residuals' Jacobian at these poses). A check on an unchanged rig then fails in about
    1 − level of days. ``stored``: the calibration's own held-out errors (e_t_mm,
    theta_t_deg: cross-validated, every pose held out once): where they are larger than the
    simulated sessions' mean (a closed-form solver is less efficient than the likelihood the
    model assumes), the quantiles are scaled up by that ratio. {"tolerance_mm",
    "tolerance_deg", "level", "n_poses", "scaled": the two ratios applied}."""
    rng = np.random.default_rng(seed)
    nm = noise if fr is None else noise.for_bodies(fr.bodies)
    q = len(nm.cov)
    K = np.linalg.cholesky(nm.cov)
    n = max(int(n_poses) if fr is None else fr.n, 1)
    r = rng.standard_normal((sessions, n, q)) @ K.T
    cc = None if fr is None else nm.calibration_for(fr)
    if cc is not None:
        blocks, C = cc
        J = _cal_jacobian(fr, blocks)  # type: ignore[arg-type]
        Lc = np.linalg.cholesky(C + 1e-18 * np.eye(len(C)))
        shared = rng.standard_normal((sessions, len(C))) @ Lc.T @ J.T
        r = r + shared.reshape(sessions, n, q)
    et = np.zeros(sessions)
    th = np.zeros(sessions)
    for i in range(len(nm.bodies)):
        et += np.linalg.norm(r[:, :, 6 * i:6 * i + 3], axis=2).mean(axis=1)
        th += np.linalg.norm(r[:, :, 6 * i + 3:6 * i + 6], axis=2).mean(axis=1)
    f_t = f_r = 1.0
    if stored:
        if np.isfinite(stored.get("e_t_mm", np.nan)):
            f_t = max(1.0, float(stored["e_t_mm"]) / float(et.mean()))
        if np.isfinite(stored.get("theta_t_deg", np.nan)):
            f_r = max(1.0, float(stored["theta_t_deg"]) / float(th.mean()))
    return {"tolerance_mm": f_t * float(np.quantile(et, level)),
            "tolerance_deg": f_r * float(np.quantile(th, level)), "level": level,
            "n_poses": n, "scaled": [f_t, f_r]}
