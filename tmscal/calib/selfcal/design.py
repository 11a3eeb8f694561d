"""Pose selection for the force-torque self-calibration: observability indices and DETMAX.

Pure numerics, no I/O (docs/selfcal.md, "Pose selection").

The identification Jacobian of one configuration is a 6 × L block Jᵢ (rows: the wrench
channels Fx, Fy, Fz in N and Tx, Ty, Tz in N·m, each divided by its channel's noise so that
they are unitless and comparable; columns: the L identifiable parameters). A design is a set
of m configurations; its Jacobian J stacks their blocks (6m × L) and its information matrix
is M = JᵀJ = Σ JᵢᵀJᵢ.

- :func:`observability` gives the five observability indices O1…O5 of a (column-scaled)
  Jacobian from ITS singular values σ1 ≥ … ≥ σL — not those of JᵀJ (Sun & Hollerbach 2008;
  Joubair et al. 2016 found O1 best for force-torque self-calibration).
- :func:`detmax` selects k configurations from a candidate pool maximising det(JᵀJ) by
  Mitchell's (1974) exchange algorithm with excursions and failure sets. At a fixed m,
  maximising det(JᵀJ) is maximising O1 (O1 = det(J̃ᵀJ̃)^{1/2L}/√m, and column scaling only
  multiplies the determinant by a constant), so DETMAX is "the selection by O1" of
  Joubair et al. 2016.
- :func:`select_by_index` is the greedy selection by any one index, for the comparison of
  the indices (Joubair et al. 2016, Table 4).
- :func:`candidate_pool` draws configurations uniformly within the joint limits.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

#: a design whose column-scaled information matrix has eigenvalues below this fraction of its
#: largest leaves a parameter combination unobserved (its J a condition number above ~1e6)
RANK_RTOL = 1e-12
#: the observability indices, in order
INDICES = ("O1", "O2", "O3", "O4", "O5")


# --- observability indices ------------------------------------------------------------------

def scale_columns(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column scaling of an identification Jacobian (Hollerbach & Wampler 1996): J̃ = J H with
    h_j = 1/‖J_:,j‖ (a zero column keeps h_j = 1). Returns ``(J̃, h)``; a parameter step of
    the scaled problem Δ̃ maps back as Δ = h Δ̃."""
    J = np.asarray(J, dtype=float)
    norms = np.linalg.norm(J, axis=0)
    h = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
    return J * h, h


def _indices_from_singular(sv: np.ndarray, m: int, zero: np.ndarray) -> dict[str, np.ndarray]:
    """O1…O5 from singular values ``sv`` (…, L) sorted in decreasing order; ``zero`` (…)
    marks rank-deficient sets (every index 0 there). Products in log space."""
    with np.errstate(divide="ignore", invalid="ignore"):
        safe = np.where(sv > 0, sv, 1.0)
        s1, sl = safe[..., 0], safe[..., -1]
        out = {
            "O1": np.exp(np.mean(np.log(safe), axis=-1)) / math.sqrt(m),
            "O2": sl / s1,
            "O3": sl,
            "O4": sl * sl / s1,
            "O5": 1.0 / np.sum(1.0 / safe, axis=-1),
        }
    return {k: np.where(zero, 0.0, v) for k, v in out.items()}


def observability(J_scaled: np.ndarray, m: int, rtol: float | None = None) -> dict[str, float]:
    """The observability indices of an identification Jacobian (Sun & Hollerbach 2008).

    ``J_scaled`` (rows × L, unitless: rows weighted by channel noise, columns scaled by
    :func:`scale_columns`) stacks the blocks of ``m`` configurations; σ1 ≥ … ≥ σL are the
    singular values of ``J_scaled`` itself (not of JᵀJ)::

        O1 = (σ1 σ2 ⋯ σL)^(1/L) / √m     (the geometric mean; the exponent is 1/L)
        O2 = σL / σ1                     (the inverse condition number)
        O3 = σL                          (the minimum singular value)
        O4 = σL² / σ1                    (the noise amplification index)
        O5 = 1 / Σ (1/σj)

    O1 is computed in log space (the product of L singular values over- or underflows). A
    rank-deficient Jacobian (σL ≤ ``rtol``·σ1, default max(rows, L)·eps, the rank rule of
    ``numpy.linalg.matrix_rank``) gives 0 for every index: a design that leaves a parameter
    unobserved observes nothing about it. Returns ``{"O1": …, …, "O5": …}`` (floats).
    """
    J = np.asarray(J_scaled, dtype=float)
    if J.ndim != 2 or J.shape[1] == 0 or J.shape[0] == 0:
        raise ValueError(f"observability: expected a non-empty 2-D Jacobian, got {J.shape}")
    if m < 1:
        raise ValueError(f"observability: m = {m} configurations; expected at least one")
    sv = np.linalg.svd(J, compute_uv=False)
    if len(sv) < J.shape[1]:  # fewer rows than parameters: rank-deficient
        sv = np.concatenate([sv, np.zeros(J.shape[1] - len(sv))])
    tol = (max(J.shape) * np.finfo(float).eps) if rtol is None else rtol
    zero = np.asarray(sv[-1] <= tol * sv[0])
    return {k: float(v) for k, v in _indices_from_singular(sv, m, zero).items()}


def _indices_from_information(M: np.ndarray, m: int) -> dict[str, np.ndarray]:
    """O1…O5 of designs given by their information matrices M (…, L, L), after column
    scaling (M̃ = H M H, h_j = 1/√M_jj): σ(J̃) = √eig(M̃)."""
    d = np.sqrt(np.clip(np.diagonal(M, axis1=-2, axis2=-1), 1e-300, None))
    Ms = M / (d[..., :, None] * d[..., None, :])
    ev = np.linalg.eigvalsh(Ms)[..., ::-1]
    sv = np.sqrt(np.clip(ev, 0.0, None))
    zero = sv[..., -1] <= sv[..., 0] * M.shape[-1] * 1e-12
    return _indices_from_singular(sv, m, zero)


# --- designs: information and log-determinant ------------------------------------------------

def _blocks(J_blocks: np.ndarray) -> np.ndarray:
    B = np.asarray(J_blocks, dtype=float)
    if B.ndim != 3 or B.shape[0] == 0 or B.shape[2] == 0:
        raise ValueError(f"expected Jacobian blocks of shape (N, rows, L), got {B.shape}")
    if not np.all(np.isfinite(B)):
        raise ValueError("the Jacobian blocks hold a non-finite value")
    return B


def _prescaled(J_blocks: np.ndarray) -> np.ndarray:
    """The blocks with the pool's columns scaled to unit norm: det(JᵀJ) of every design
    changes by the same factor, so a D-optimal selection is unchanged, and the information
    matrices are well conditioned whatever the parameters' units."""
    B = _blocks(J_blocks)
    _, h = scale_columns(B.reshape(-1, B.shape[2]))
    return B * h


def information(J_blocks: np.ndarray, idx: np.ndarray | list[int]) -> np.ndarray:
    """The information matrix M = Σᵢ JᵢᵀJᵢ (L × L) of the design ``idx`` (pool indices)."""
    B = _blocks(J_blocks)[np.asarray(idx, dtype=int)]
    return np.einsum("nri,nrj->ij", B, B)


def log_det(J_blocks: np.ndarray, idx: np.ndarray | list[int]) -> float:
    """log det(JᵀJ) of the design ``idx``: the D-criterion DETMAX maximises. −inf when the
    design leaves a parameter combination unobserved: numerically, when the smallest
    eigenvalue of the column-scaled M (unit diagonal) is below ``RANK_RTOL`` of the largest
    (round-off gives a rank-deficient M a tiny positive determinant otherwise)."""
    M = information(J_blocks, idx)
    d = np.sqrt(np.diagonal(M))
    if np.any(d == 0):
        return -math.inf
    ev = np.linalg.eigvalsh(M / np.outer(d, d))
    if ev[0] <= RANK_RTOL * ev[-1]:
        return -math.inf
    sign, ld = np.linalg.slogdet(M)
    return float(ld) if sign > 0 else -math.inf


class _Design:
    """A design under exchange: its pool indices, information matrix M (with a tiny ridge so
    that it stays invertible while rank-deficient) and the rank-6 update gains."""

    def __init__(self, B: np.ndarray, idx: list[int], ridge: float) -> None:
        self.B, self.ridge = B, ridge
        self.idx = list(idx)
        L = B.shape[2]
        self.M = information(B, self.idx) if self.idx else np.zeros((L, L))

    def _gain(self, rows: np.ndarray, sign: float) -> np.ndarray:
        """log det(I ± Jᵢ M⁻¹ Jᵢᵀ) for the blocks ``rows`` (the change of log det M when
        block i is added (+) or removed (−))."""
        L = self.M.shape[0]
        W = np.linalg.inv(self.M + self.ridge * np.eye(L))
        B = self.B[rows]  # (n, r, L)
        S = (B @ W) @ B.transpose(0, 2, 1)
        s, ld = np.linalg.slogdet(np.eye(B.shape[1]) + sign * S)
        return np.where(s > 0, ld, -np.inf)

    def add_best(self) -> int:
        """Add the candidate (not in the design) that increases det M most."""
        free = np.setdiff1d(np.arange(len(self.B)), self.idx)
        i = int(free[int(np.argmax(self._gain(free, +1.0)))])
        self.idx.append(i)
        self.M += self.B[i].T @ self.B[i]
        return i

    def delete_best(self) -> int:
        """Delete the design point whose removal decreases det M least."""
        j = int(np.argmax(self._gain(np.asarray(self.idx), -1.0)))
        i = self.idx.pop(j)
        self.M -= self.B[i].T @ self.B[i]
        return i

    def key(self) -> frozenset[int]:
        return frozenset(self.idx)

    def copy(self) -> _Design:
        d = _Design.__new__(_Design)
        d.B, d.ridge, d.idx, d.M = self.B, self.ridge, list(self.idx), self.M.copy()
        return d


def _ridge(B: np.ndarray) -> float:
    """A ridge negligible against any real design: 1e-9 of one configuration's mean diagonal
    information."""
    mean_diag = float(np.mean(np.einsum("nri,nri->i", B, B))) / B.shape[0]
    return 1e-9 * (mean_diag if mean_diag > 0 else 1.0)


def _check_k(N: int, k: int) -> None:
    if not 1 <= k <= N:
        raise ValueError(f"cannot select {k} configurations from a pool of {N}")


def _greedy_d(B: np.ndarray, k: int, ridge: float) -> _Design:
    """Sequential D-optimal design: from empty, add the candidate that increases
    det(JᵀJ + ridge·I) most, k times."""
    d = _Design(B, [], ridge)
    for _ in range(k):
        d.add_best()
    return d


def _ridge_log_det(d: _Design) -> float:
    sign, ld = np.linalg.slogdet(d.M + d.ridge * np.eye(d.M.shape[0]))
    return float(ld) if sign > 0 else -math.inf


def _excursion(best: _Design, k: int, up: bool, failures: set[frozenset[int]],
               max_len: int) -> tuple[_Design, list[frozenset[int]], bool]:
    """One excursion of Mitchell's DETMAX from the k-point design ``best``: first a step up
    (add) or down (delete), then toward k again — except from a design in the failure set,
    where it goes further away. Returns the design it ends on, the designs it visited and
    whether it was cut off for exceeding ``max_len`` points away from k."""
    d = best.copy()
    path: list[frozenset[int]] = []
    seen: set[frozenset[int]] = set()
    N = len(d.B)

    def step(add: bool) -> bool:
        """Add or delete one point; False when the pool or the design is exhausted."""
        if add and len(d.idx) < N:
            d.add_best()
        elif not add and len(d.idx) > 1:
            d.delete_best()
        else:
            return False
        return True

    if not step(up):
        return d, path, True
    while True:
        j = len(d.idx) - k
        if j == 0:
            return d, path, False
        if abs(j) > max_len:
            return d, path, True
        key = d.key()
        away = key in failures or key in seen  # a design met again: go on, never cycle
        path.append(key)
        seen.add(key)
        if not step((j > 0) == away):           # cannot go further: a cut-off excursion
            return d, path, True


def detmax(J_blocks: np.ndarray, k: int, start: np.ndarray | list[int] | None = None,
           rng: np.random.Generator | int | None = None, max_excursion: int = 6,
           max_excursions: int = 2000) -> np.ndarray:
    """Select ``k`` configurations of a candidate pool maximising det(JᵀJ) (D-optimal), by
    Mitchell's (1974) DETMAX exchange algorithm.

    ``J_blocks`` (N, r, L): the identification Jacobian of each candidate (r = 6 wrench rows
    weighted by channel noise, L parameters). From the start design (``start``: k distinct
    pool indices; default the sequential D-optimal design, each candidate added in turn where
    it increases det most), excursions add the candidate that increases det(JᵀJ) most and
    delete the design point whose removal decreases it least, via the rank-r updates
    det(M ± JᵢᵀJᵢ) = det M · det(I ± Jᵢ M⁻¹ Jᵢᵀ) on the Cholesky factor of M. An excursion
    that returns to k points with a larger determinant is kept and the failure sets are
    cleared; one that does not puts the designs it visited into the failure sets, and the
    next excursion goes further from k where it meets one. The search ends when excursions
    of ``max_excursion`` points fail both upward and downward, or after ``max_excursions``.

    While the design is rank-deficient M carries a ridge of 1e-9 of one configuration's mean
    information, so the updates stay defined. The result is never worse than the start:
    log det(JᵀJ) of the returned design ≥ that of the start (the start itself is returned if
    nothing better was found). ``rng`` is accepted for a reproducible interface (the
    exchange itself is deterministic). Returns the k pool indices, sorted.
    """
    B = _prescaled(J_blocks)
    N = len(B)
    _check_k(N, k)
    del rng  # deterministic; kept for the interface
    ridge = _ridge(B)
    if start is None:
        best = _greedy_d(B, k, ridge)
    else:
        s = np.asarray(start, dtype=int).ravel()
        if len(s) != k or len(np.unique(s)) != k or s.min() < 0 or s.max() >= N:
            raise ValueError(f"detmax: the start must be {k} distinct indices in 0…{N - 1}")
        best = _Design(B, [int(i) for i in s], ridge)
    start_idx = np.sort(np.asarray(best.idx))
    best_val = _ridge_log_det(best)
    failures: set[frozenset[int]] = set()
    exhausted = {True: False, False: False}
    up = True
    for _ in range(max_excursions):
        if k == N or all(exhausted.values()):
            break
        d, path, cut = _excursion(best, k, up, failures, max_excursion)
        val = -math.inf if cut else _ridge_log_det(d)
        if val > best_val + 1e-10 * max(1.0, abs(best_val)):
            best, best_val = d, val
            failures.clear()
            exhausted = {True: False, False: False}
            continue
        failures.update(path)
        if cut:
            exhausted[up] = True
            up = not up
    result = np.sort(np.asarray(best.idx))
    return result if log_det(B, result) >= log_det(B, start_idx) else start_idx


def select_by_index(J_blocks: np.ndarray, k: int, index: str = "O1", seed_size: int | None = None,
                    rng: np.random.Generator | int | Sequence[int] | None = None,
                    candidates_per_step: int = 256) -> np.ndarray:
    """Greedy selection of ``k`` configurations by one observability index, for the
    comparison of the indices (Joubair et al. 2016, Table 4).

    ``index`` "O1": the sequential D-optimal design (each step adds the candidate that
    increases det(JᵀJ) most, which at a fixed count is the one that increases O1 most;
    every candidate is tried). "O2"…"O5": the first ``seed_size`` configurations of that
    design (default ⌈L/r⌉ + 1, the fewest that can observe every parameter, plus one), then
    each step adds, of ``candidates_per_step`` candidates drawn at random from the rest
    (all of them in a smaller pool), the one whose column-scaled design has the largest
    index. Returns the k pool indices in the order chosen.
    """
    B = _prescaled(J_blocks)
    N, r, L = B.shape
    _check_k(N, k)
    if index not in INDICES:
        raise ValueError(f"unknown observability index {index!r}; expected one of {INDICES}")
    ridge = _ridge(B)
    s0 = min(k, seed_size if seed_size is not None else -(-L // r) + 1)
    d = _greedy_d(B, k if index == "O1" else s0, ridge)
    gen = np.random.default_rng(rng)
    while len(d.idx) < k:
        free = np.setdiff1d(np.arange(N), d.idx)
        if len(free) > candidates_per_step:
            free = gen.choice(free, candidates_per_step, replace=False)
        Mc = d.M[None] + np.einsum("nri,nrj->nij", B[free], B[free])
        score = _indices_from_information(Mc, len(d.idx) + 1)[index]
        i = int(free[int(np.argmax(score))])
        d.idx.append(i)
        d.M += B[i].T @ B[i]
    return np.asarray(d.idx)


def candidate_pool(joint_limits_rad: np.ndarray, count: int,
                   rng: np.random.Generator | int | None = None) -> np.ndarray:
    """``count`` joint configurations (count, n) rad drawn uniformly within the joint limits
    ``joint_limits_rad`` (n, 2: lower, upper) — the candidate pool of the selection."""
    lim = np.asarray(joint_limits_rad, dtype=float)
    if lim.ndim != 2 or lim.shape[1] != 2 or not np.all(np.isfinite(lim)):
        raise ValueError(f"joint limits: expected a finite (n, 2) array, got {lim.shape}")
    if np.any(lim[:, 1] < lim[:, 0]):
        raise ValueError("joint limits: a lower limit is above its upper limit")
    if count < 1:
        raise ValueError(f"candidate pool: count = {count}; expected at least 1")
    gen = np.random.default_rng(rng)
    return lim[:, 0] + gen.random((count, len(lim))) * (lim[:, 1] - lim[:, 0])
