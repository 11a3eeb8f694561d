"""The maximum-likelihood fit of one hypothesis (docs/lab-day.md): the named blocks' rigid
changes (or the arm's joint offsets) by whitened least squares from a closed-form start, the
whitening fixed at the best single change (:func:`fit`, :class:`Fit`). Units as
:mod:`.model`: mm, deg in the residuals; 4×4 mm poses."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from ...errors import CalibrationError
from .model import (
    RANK_TOL,
    Frames,
    NoiseModel,
    _apply,
    _cal_jacobian,
    _coil_delta,
    _delta,
    _size,
    _start,
    residuals,
)

__all__ = ["Fit", "fit"]


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
