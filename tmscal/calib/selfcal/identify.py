"""Identifiability and identification of the arm model from gravity wrenches (Joubair, Zhao,
Bigras and Bonev 2016), with the column scaling of Hollerbach and Wampler 1996. Pure numerics,
no I/O; docs/selfcal.md ("Identifiability", "Identification").

Units: wrenches [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame; parameters as
``ArmModel.parameter_names`` / ``parameter_units`` (rad, mm, N, N·m); positions mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg

from ..lsq import levenberg_marquardt
from .model import ArmModel, forward, jacobian, wrench

__all__ = ["Identifiability", "identifiable", "Fit", "identify", "position_errors",
           "error_stats", "ZERO_COLUMN_RTOL", "RANK_RTOL", "ZERO_REASON", "check_data"]

#: a column is "zero" when its norm is below this fraction of the largest column norm
ZERO_COLUMN_RTOL = 1e-9
#: numerical rank: singular values of the column-scaled Jacobian above this fraction of the
#: largest count (unit-norm columns: ~1e-16 is exact dependence, 1e-8 far from it)
RANK_RTOL = 1e-8
ZERO_REASON = "zero column: does not change the gravity wrench"


@dataclass
class Identifiability:
    """Which parameters a Jacobian identifies.

    ``kept``: identifiable parameter names (order of ``names``); ``removed``: [(name, reason)]
    in the order removed, the reason "zero column: …" or "dependent (confounded with a, b)";
    ``rank``: the numerical rank of the Jacobian; ``cond``: the condition number of the kept
    columns, scaled to unit norm; ``qr_rank``, ``qr_kept``: the rank and the first ``qr_rank``
    pivots of QR with column pivoting on the scaled nonzero columns, the cross-check."""

    names: list[str]
    kept: list[str]
    removed: list[tuple[str, str]]
    rank: int
    cond: float
    qr_rank: int
    qr_kept: list[str] = field(default_factory=list)

    @property
    def kept_index(self) -> np.ndarray:
        """Indices of ``kept`` in ``names``."""
        pos = {n: i for i, n in enumerate(self.names)}
        return np.array([pos[n] for n in self.kept], dtype=int)

    def reason(self, name: str) -> str | None:
        """Why ``name`` was removed, or None if it is kept."""
        return dict(self.removed).get(name)

    def summary(self) -> str:
        """A few lines: the counts, the kept names, each removed name with its reason."""
        lines = [f"{len(self.kept)} of {len(self.names)} parameters identifiable "
                 f"(rank {self.rank}, condition number {self.cond:.3g}; QR pivoting rank "
                 f"{self.qr_rank})", "identifiable: " + ", ".join(self.kept)]
        lines += [f"  {n}: {r}" for n, r in self.removed]
        return "\n".join(lines)


def _rank_cond(R: np.ndarray) -> tuple[int, float]:
    """(numerical rank, σ1/σ_rank) of a matrix with unit-norm columns."""
    s = np.linalg.svd(R, compute_uv=False)
    if s.size == 0 or s[0] == 0:
        return 0, np.inf
    r = int(np.sum(s > RANK_RTOL * s[0]))
    return r, float(s[0] / s[r - 1])


def _confounders(R: np.ndarray, j: int, kept: list[int], names: Sequence[str]) -> str:
    """The kept parameters whose columns combine into column j (least squares on the kept;
    R has the singular values and column relations of the scaled Jacobian)."""
    coef, *_ = np.linalg.lstsq(R[:, kept], R[:, j], rcond=None)
    big = np.abs(coef) > 1e-6 * max(np.abs(coef).max(), 1e-300)
    return ", ".join(names[kept[i]] for i in np.flatnonzero(big))


def identifiable(J: Any, names: Sequence[str]) -> Identifiability:
    """Identifiable parameters of a Jacobian J (rows × len(names)), as Joubair et al. 2016 do:
    remove the zero columns (norm < ``ZERO_COLUMN_RTOL`` × the largest), scale the rest to unit
    norm (Hollerbach and Wampler 1996), then, while the rank is below the number of columns,
    remove one column: among those whose removal keeps the rank, the one whose removal leaves
    the lowest condition number σ1/σ_rank (ties within 1e-9 relative: the one latest in
    ``names``). QR with column pivoting on the same scaled columns cross-checks the rank."""
    J = np.asarray(J, dtype=float)
    names = list(names)
    if J.ndim != 2 or J.shape[1] != len(names):
        raise ValueError(f"J must be (rows, {len(names)}), got shape {J.shape}")
    norms = np.linalg.norm(J, axis=0)
    top = norms.max() if norms.size else 0.0
    zero = [j for j in range(len(names)) if norms[j] <= ZERO_COLUMN_RTOL * top]
    removed = [(names[j], ZERO_REASON) for j in zero]
    cols = [j for j in range(len(names)) if j not in zero]
    qr_rank, qr_kept, R = _qr_check(J[:, cols] / norms[cols], [names[j] for j in cols])
    local = list(range(len(cols)))                       # indices into cols / R's columns
    rank, cond = _rank_cond(R)
    dependent: list[int] = []
    while len(local) > rank:
        best: tuple[float, int] | None = None
        for pos in reversed(range(len(local))):           # latest first: wins ties
            trial = local[:pos] + local[pos + 1:]
            r, c = _rank_cond(R[:, trial])
            if r == rank and (best is None or c < best[0] * (1 - 1e-9)):
                best = (c, pos)
        if best is None:                                  # cannot happen for exact rank
            raise ValueError("no column can be removed without losing rank")
        dependent.append(local.pop(best[1]))
        cond = best[0]
    kept = [cols[i] for i in local]
    cnames = [names[j] for j in cols]
    removed += [(names[cols[i]], "dependent (confounded with "
                 f"{_confounders(R, i, local, cnames)})") for i in dependent]
    return Identifiability(names=names, kept=[names[j] for j in sorted(kept)], removed=removed,
                           rank=rank, cond=cond, qr_rank=qr_rank, qr_kept=qr_kept)


def _qr_check(Js: np.ndarray, names: list[str]) -> tuple[int, list[str], np.ndarray]:
    """(rank, first-rank pivots, R) of QR with column pivoting on unit-norm columns Js; R
    (columns back in Js's order) has Js's singular values and column relations (Js = Q R)."""
    if Js.shape[1] == 0:
        return 0, [], np.zeros((0, 0))
    R, piv = scipy.linalg.qr(Js, mode="r", pivoting=True)
    R = R[:Js.shape[1]]
    d = np.abs(np.diag(R))
    r = int(np.sum(d > RANK_RTOL * d[0]))
    return r, [names[i] for i in piv[:r]], R[:, np.argsort(piv)]


@dataclass
class Fit:
    """Result of :func:`identify`.

    ``model``: the identified model (parameters not estimated keep the start's values);
    ``parameters``: the estimated names; ``covariance``: their covariance (len × len, the
    units of ``parameter_units``) from the stated channel noise, (Jᵀ W J)⁻¹ with W = diag(1/σ²);
    ``std``: its square-rooted diagonal; ``reduced_chi2``: Σ (r/σ)² / (rows − parameters) at
    the solution (≈ 1 when the stated σ is right; multiply the covariance by it otherwise);
    ``rms``: residual RMS per channel (6,) N, N·m; ``iterations``; ``converged``: the relative
    step fell below ``rtol`` before the cap."""

    model: ArmModel
    parameters: list[str]
    covariance: np.ndarray
    std: np.ndarray
    reduced_chi2: float
    rms: np.ndarray
    iterations: int
    converged: bool


def _keep_index(model: ArmModel, keep: Any) -> np.ndarray:
    names = model.parameter_names()
    if isinstance(keep, Identifiability):
        keep = keep.kept
    pos = {n: i for i, n in enumerate(names)}
    bad = [k for k in keep if k not in pos]
    if bad:
        raise ValueError(f"unknown parameter names: {bad}")
    return np.array(sorted(pos[k] for k in keep), dtype=int)


def check_data(model: ArmModel, q: Any, w: Any, sigma: Any) -> tuple[np.ndarray, ...]:
    q = np.atleast_2d(np.asarray(q, dtype=float))
    w = np.atleast_2d(np.asarray(w, dtype=float))
    sigma = np.asarray(sigma, dtype=float)
    if q.ndim != 2 or q.shape[1] != model.n_joints:
        raise ValueError(f"q must be (m, {model.n_joints}) rad, got shape {q.shape}")
    if w.shape != (len(q), 6):
        raise ValueError(f"wrench_meas must be ({len(q)}, 6), got shape {w.shape}")
    if sigma.shape != (6,) or np.any(sigma <= 0) or not np.all(np.isfinite(sigma)):
        raise ValueError("sigma must be six positive noise levels (N ×3, N·m ×3)")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(w))):
        raise ValueError("q and wrench_meas must be finite")
    return q, w, sigma


def identify(model0: ArmModel, q: Any, wrench_meas: Any, sigma: Any, keep: Any,
             max_iter: int = 50, rtol: float = 1e-10) -> Fit:
    """Fit the parameters ``keep`` (names, or an :class:`Identifiability`) of ``model0`` to
    measured wrenches ``wrench_meas`` (m, 6) [N, N·m, sensor frame] at joints q (m, n) rad.

    Gauss–Newton with Levenberg–Marquardt damping: rows whitened by the channel noise
    ``sigma`` (6,) (N ×3, N·m ×3), columns scaled to unit norm (h_j = 1/‖J_:,j‖, Hollerbach
    and Wampler 1996), solve, unscale. Stops when ‖Δp‖ ≤ rtol · max(‖p‖, 1) over the estimated
    parameters (their units), or after ``max_iter`` iterations (``converged`` False)."""
    q, w, sigma = check_data(model0, q, wrench_meas, sigma)
    idx = _keep_index(model0, keep)
    names = model0.parameter_names()
    inv_s = np.tile(1.0 / sigma, len(q))
    p = model0.vector()

    def evaluate(pv: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        r = (w - wrench(model0.with_vector(pv), q)).ravel() * inv_s
        # the residual is measured − model: its derivative is −J
        return r, (-jacobian(model0.with_vector(pv), q)[:, idx] * inv_s[:, None]
                   if jac else None)

    def moved(pv: np.ndarray, dx: np.ndarray) -> np.ndarray:
        out = pv.copy()
        out[idx] += dx
        return out

    sol = levenberg_marquardt(
        evaluate, p, moved, max_iter=max_iter, lam0=1e-3, lam_max=1e12, ftol=0.0,
        small_step=lambda pv, dx: bool(np.linalg.norm(dx)
                                       <= rtol * max(float(np.linalg.norm(pv[idx])), 1.0)))
    p, r, it, converged = sol.state, sol.residuals, sol.iterations, sol.converged
    cost = sol.cost
    model = model0.with_vector(p)
    Jw = jacobian(model, q)[:, idx] * inv_s[:, None]
    cov = np.linalg.pinv(Jw.T @ Jw)
    dof = max(len(r) - len(idx), 1)
    rms = np.sqrt(np.mean((w - wrench(model, q)) ** 2, axis=0))
    return Fit(model=model, parameters=[names[i] for i in idx], covariance=cov,
               std=np.sqrt(np.clip(np.diag(cov), 0, None)), reduced_chi2=cost / dof, rms=rms,
               iterations=it, converged=bool(converged))


def position_errors(model_true: ArmModel, model_est: ArmModel, q: Any,
                    tcp_mm: Any = (0.0, 0.0, 0.0)) -> np.ndarray:
    """(m,) mm: the distance between the TCP positions that the two models' forward
    kinematics give at joints q (m, n) rad; ``tcp_mm`` is the TCP in the flange frame (mm).
    What Joubair et al. 2016 report as position error (summarise with :func:`error_stats`)."""
    tcp = np.append(np.asarray(tcp_mm, dtype=float), 1.0)
    a = forward(model_true, q) @ tcp
    b = forward(model_est, q) @ tcp
    return np.linalg.norm(a[..., :3] - b[..., :3], axis=-1)


def error_stats(errors_mm: Any) -> dict[str, float]:
    """{"mean_mm", "max_mm", "sd_mm"} of position errors (mm); SD with ddof = 1 (0 for one
    value)."""
    e = np.asarray(errors_mm, dtype=float).ravel()
    if e.size == 0:
        raise ValueError("no errors to summarise")
    return {"mean_mm": float(e.mean()), "max_mm": float(e.max()),
            "sd_mm": float(e.std(ddof=1)) if e.size > 1 else 0.0}
