"""SGO: the stochastic global optimisation of Ha, Kang & Park (2016) for A X = Z B.

Frames (docs/conventions.md): A = base_from_flange, B = tracker_from_marker,
C = tracker_from_probe, X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker;
4×4 mm. The cost (the Panda/Vicra comparison's Eq. 4, docs/methods.md) is

    f = ½ Σ ‖R_Ai R_X − R_Z R_Bi‖²_F + (ζ/2) Σ ‖R_Ai t_X + t_Ai − R_Z t_Bi − t_Z‖²

with positions in mm and ζ = ``zeta`` (default 0.5, the value that comparison uses; it does not
state the length unit, tmscal's is mm, where the ~1.5 m tracker lever arm makes the
translation term the dominant one). With two bodies the probe adds the same terms for Y and
C with the same Z (X, Y, Z jointly).

1. **Translation elimination.** The cost is quadratic in the translations; minimising them
   out leaves ζ/2 (zᵀ H z − 2 gᵀ z + c) with z = vec R_Z (a 9 × 9 form computed once). The
   rotation term is 3 n m − Σ_j zᵀ K_j x_j, K_j = Σ_i R_Ni ⊗ R_Ai. So f on SO(3)^(m+1) is a
   quadratic form in the stacked vec of the rotations, evaluated in O(1) per sample.
2. **Local search** on SO(3) × SO(3) (× SO(3)): Newton steps R ← R exp(ŵ) with the exact
   Riemannian gradient and Hessian of that form, shifted to positive definite where it is not,
   and a backtracking line search along the geodesic.
3. **Global phase**: rounds of ``samples`` uniform random rotation tuples; the samples of a
   round whose cost is below the ``gamma`` (0.2) quantile of all costs seen so far form the
   reduced sample; a local search starts from each reduced sample with no lower-cost reduced
   sample within ``cluster_rad`` (clustering); minima closer than ``merge_rad`` (0.1 rad,
   largest angle over the frames) are merged. After a round, with w minima from N local
   searches, the Bayesian estimate of the number of minima w(N − 1)/(N − w − 2) (Boender &
   Rinnooy Kan) stops the search once it is within ``stop_tol`` (5 %) of w.
   ``seed`` (default 0) makes a solve reproducible.

Translations of the best minimum are then solved by linear least squares with the rotations
fixed (the same elimination).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import CalibrationError
from ..geometry import matrix_from_rotvec, random_rotation
from .calibration import Calibration
from .classic import bodies_of, rigid_calibration
from .linear import resolve_translations
from .methods import register_method

__all__ = ["SgoCost", "solve_sgo"]

_E = np.zeros((3, 3, 3))  # _E[a] = hat(e_a)
_E[0, 2, 1], _E[0, 1, 2] = 1.0, -1.0
_E[1, 0, 2], _E[1, 2, 0] = 1.0, -1.0
_E[2, 1, 0], _E[2, 0, 1] = 1.0, -1.0
_EE = 0.5 * (np.einsum("aij,bjk->abik", _E, _E) + np.einsum("bij,ajk->abik", _E, _E))


def _vec(R: np.ndarray) -> np.ndarray:
    """Column-major vec of 3×3 matrices (…, 3, 3) → (…, 9)."""
    return np.swapaxes(R, -1, -2).reshape(R.shape[:-2] + (9,))


class SgoCost:
    """f(R_Z, R_X1[, R_X2]) = ½ vᵀ Q v + qᵀ v + const with v = [vec R_Z; vec R_X1; …]."""

    def __init__(self, A: np.ndarray, bodies: list[np.ndarray], zeta: float) -> None:
        n, m = len(A), len(bodies)
        RA, tA = A[:, :3, :3], A[:, :3, 3]
        k = 9 * (m + 1)
        Q = np.zeros((k, k))
        Ms, Js, ys = [], [], []
        for j, N in enumerate(bodies):
            K = np.einsum("nab,ncd->acbd", N[:, :3, :3], RA).reshape(9, 9)
            Q[:9, 9 * (j + 1):9 * (j + 2)] = -K
            Q[9 * (j + 1):9 * (j + 2), :9] = -K.T
            # R_Z t_N = (t_Nᵀ ⊗ I₃) vec R_Z
            Ms.append(np.einsum("nc,ab->nacb", N[:, :3, 3], np.eye(3)).reshape(3 * n, 9))
            J = np.zeros((n, 3, 3 * (m + 1)))
            J[:, :, 3 * j:3 * j + 3] = RA
            J[:, :, -3:] = -np.eye(3)
            Js.append(J.reshape(3 * n, -1))
            ys.append(tA.reshape(-1))
        M, J, y = np.vstack(Ms), np.vstack(Js), np.concatenate(ys)
        Qj = np.linalg.qr(J)[0]
        Mp, yp = M - Qj @ (Qj.T @ M), y - Qj @ (Qj.T @ y)
        Q[:9, :9] = zeta * Mp.T @ Mp
        self.Q = Q
        self.q = np.zeros(k)
        self.q[:9] = -zeta * Mp.T @ yp
        self.const = 3.0 * n * m + 0.5 * zeta * float(yp @ yp)
        self.m = m
        #: rounding level of a cost value (the quadratic form's size at unit rotations)
        self.f_eps = 1e-14 * float(np.abs(Q).sum())

    def __call__(self, R: np.ndarray) -> np.ndarray:
        """Cost of rotation tuples R (…, m + 1, 3, 3) (order Z, X1, …)."""
        v = _vec(R).reshape(R.shape[:-3] + (-1,))
        return 0.5 * np.einsum("...i,ij,...j->...", v, self.Q, v) + v @ self.q + self.const

    def grad_hess(self, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Riemannian gradient and Hessian at R (m + 1, 3, 3) in body coordinates
        (R_k ← R_k exp(ŵ_k)), each of size 3(m + 1)."""
        b = self.m + 1
        gE = self.Q @ _vec(R).reshape(-1) + self.q
        L = np.zeros((9 * b, 3 * b))
        H2 = np.zeros((3 * b, 3 * b))
        for k in range(b):
            L[9 * k:9 * k + 9, 3 * k:3 * k + 3] = _vec(R[k] @ _E).T
            G = gE[9 * k:9 * k + 9].reshape(3, 3).T
            H2[3 * k:3 * k + 3, 3 * k:3 * k + 3] = np.einsum("ij,ik,abkj->ab", G, R[k], _EE)
        return L.T @ gE, L.T @ self.Q @ L + H2


def local_search(cost: SgoCost, R: np.ndarray, max_iter: int = 60) -> tuple[np.ndarray, float]:
    """Damped Newton descent on SO(3)^(m+1) from R; returns (R, f)."""
    f = float(cost(R))
    for _ in range(max_iter):
        g, H = cost.grad_hess(R)
        w, V = np.linalg.eigh(H)
        floor = 1e-9 * max(abs(w[-1]), 1e-300)
        d = -V @ ((V.T @ g) / np.maximum(np.abs(w), floor))
        if not g @ d < 0:
            break
        t = 1.0
        while t > 1e-10:
            Rn = R @ matrix_from_rotvec((t * d).reshape(-1, 3))
            fn = float(cost(Rn))
            if fn <= f + 1e-4 * t * (g @ d) + cost.f_eps:
                break
            t *= 0.5
        else:
            break
        R, fdrop, f = Rn, f - fn, fn
        if np.max(np.abs(t * d)) < 1e-13 or (t < 1.0 and fdrop <= cost.f_eps):
            break
    return R, f


def _angles(R: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Largest rotation angle between corresponding frames of tuples R (…, b, 3, 3) and S."""
    tr = np.einsum("...kij,...kij->...k", R, S)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)).max(axis=-1)


def global_search(cost: SgoCost, rng: np.random.Generator, samples: int, gamma: float,
                  cluster_rad: float, merge_rad: float, stop_tol: float, max_rounds: int
                  ) -> tuple[np.ndarray, dict[str, Any]]:
    """The clustered multistart with the Bayesian stopping rule; returns the best tuple."""
    b = cost.m + 1
    seen = np.empty(0)
    minima: list[tuple[np.ndarray, float]] = []
    n_local = 0
    rounds = 0
    while rounds < max_rounds:
        rounds += 1
        S = random_rotation(rng, samples * b).reshape(samples, b, 3, 3)
        fs = cost(S)
        seen = np.concatenate([seen, fs])
        red = np.flatnonzero(fs <= np.quantile(seen, gamma))
        red = red[np.argsort(fs[red])]
        for i, idx in enumerate(red):
            if i and _angles(S[red[:i]], S[idx][None]).min() < cluster_rad:
                continue
            Rm, fm = local_search(cost, S[idx])
            n_local += 1
            near = [j for j, (Rj, _) in enumerate(minima) if _angles(Rj, Rm) < merge_rad]
            if not near:
                minima.append((Rm, fm))
            elif fm < minima[near[0]][1]:
                minima[near[0]] = (Rm, fm)
        w = len(minima)
        if n_local > w + 2 and w * (n_local - 1) / (n_local - w - 2) <= (1.0 + stop_tol) * w:
            break
    best = min(minima, key=lambda p: p[1])
    info = {"local_searches": n_local, "minima": len(minima), "rounds": rounds,
            "cost": best[1]}
    return best[0], info


@register_method("sgo")
def solve_sgo(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, orthonormal: bool,
              seed: int = 0, zeta: float = 0.5, samples: int = 100, gamma: float = 0.2,
              cluster_rad: float = 0.5, merge_rad: float = 0.1, stop_tol: float = 0.05,
              max_rounds: int = 50) -> Calibration:
    """Ha, Kang & Park (2016); for two bodies X, Y, Z jointly with one Z (module docstring)."""
    if not zeta > 0 or not 0 < gamma <= 1 or samples < 1 or max_rounds < 1:
        raise CalibrationError("sgo: zeta must be > 0, gamma in (0, 1], samples and "
                               "max_rounds ≥ 1")
    bodies = bodies_of(A, B, C)
    cost = SgoCost(A, bodies, float(zeta))
    R, info = global_search(cost, np.random.default_rng(seed), int(samples), float(gamma),
                            float(cluster_rad), float(merge_rad), float(stop_tol),
                            int(max_rounds))
    Z, Xs = resolve_translations(A, bodies, R[0], list(R[1:]))
    return rigid_calibration("sgo", A, Z, Xs, orthonormal, seed=seed, zeta=zeta, **info)

