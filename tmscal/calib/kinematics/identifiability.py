"""Which combinations of an arm's kinematic deviations a hand/eye session identifies
(docs/kinematics.md, "The estimator"): the data Jacobian of the deviations with X, Y, Z (and
a tracker distortion) projected out, columns in tolerance units, by its singular value
decomposition. σ_k ≥ 1: identified (the poses know it better than the tolerance); 0 < σ_k < 1:
weakly identified (the prior decides); σ_k ≈ 0: not identifiable, sorted by the reason and
written in reduced echelon form so that they read as parameters. Deviations are mm or rad;
estimates and σ in tolerance units. Pure linear algebra, used by
:mod:`tmscal.calib.kinematics.estimate`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Combination", "identifiability", "ZERO_WRENCH_REASON"]

#: why a combination is not identifiable from gravity wrenches alone: it does not turn the
#: flange (a length, or a rotation that another joint's undoes), and a wrench sees only how
#: gravity turns in the sensor
ZERO_WRENCH_REASON = "does not change the gravity wrench (it does not turn the flange)"


@dataclass(frozen=True)
class Combination:
    """One direction of the deviations in tolerance units (Σ_j v_j δ_j / τ_j): ``terms``
    {parameter: v_j} (|v_j| ≥ 0.05, largest first), the data's singular value ``sigma_data``
    (≥ 1: identified), the estimate and its posterior standard deviation (tolerance units),
    and for an unidentified one the ``reason``."""

    terms: dict[str, float]
    sigma_data: float
    estimate: float
    sd: float
    reason: str | None = None
    #: the whole unit vector v over the fit's ``names`` (terms shows its main part)
    vector: np.ndarray | None = None

    def describe(self) -> str:
        """One line, e.g. "+0.71 a_2 +0.70 a_3 = +2.31 ± 0.04 (tolerance units)"."""
        lhs = " ".join(f"{v:+.2f} {k}" for k, v in self.terms.items())
        if self.reason:
            return f"{lhs}: {self.reason}"
        return f"{lhs} = {self.estimate:+.3g} ± {self.sd:.2g}"


def identifiability(names: list[str], tau: np.ndarray, delta: np.ndarray, Jd: np.ndarray,
                    n_xyz: int, nb: int, distortion: bool, vf: float = 1.0,
                    wrench_col: int | None = None
                    ) -> tuple[list[Combination], list[Combination], list[Combination]]:
    """(identified, weak, unidentified) combinations of the deviations ``names`` (module
    docstring), from the whitened data Jacobian ``Jd`` (m, n_xyz + P) at the estimate: its
    first ``n_xyz`` columns X (and Y) — 6 per body, ``nb`` bodies — then Z and, with
    ``distortion``, the tracker distortion's; then the P deviations (mm or rad), whose
    prior σ are ``tau`` and estimate ``delta``; ``vf`` the variance factor. The unidentified ones
    are sorted by reason — combinations that move no flange pose, those Z absorbs, those
    X (and Y) absorb, those only all three together absorb — each set in reduced echelon
    form (one leading parameter per combination), so that they read as parameters. With
    wrench rows (``wrench_col``: the first column of the wrench model's parameters,
    :data:`tmscal.calib.kinematics.wrench.WRENCH_NAMES`), Z absorbs with the base tilt and
    X (Y) with the sensor rotation, as the wrench sees the same directions."""
    nx = n_xyz
    Jd = _compressed(Jd)
    Jk = Jd[:, nx:] * tau                               # δ in tolerance units
    tol = 1e-7 * max(float(np.linalg.norm(Jk, 2)), 1e-300)
    Jp = _residual_of(Jd[:, :nx], Jk)
    U, sig, Vt = np.linalg.svd(Jp, full_matrices=False)
    delta_s = delta / tau
    ident: list[Combination] = []
    weak: list[Combination] = []
    for k, v in enumerate(Vt):
        if sig[k] <= tol:
            continue
        c = _combination(names, v, float(sig[k]), delta_s, vf)
        if sig[k] < 1.0:
            weak.append(Combination(c.terms, c.sigma_data, c.estimate, c.sd,
                                    "weakly identified: these poses see it less well than the "
                                    "tolerance says; spread the joints further", c.vector))
        else:
            ident.append(c)
    z_cols = list(range(6 * nb, 6 * nb + 6)) if nb else []
    x_cols = list(range(6 * nb))
    if wrench_col is not None:   # the base tilt goes with Z, the sensor rotation with X (Y)
        z_cols += [wrench_col, wrench_col + 1]
        x_cols += [wrench_col + 2, wrench_col + 3, wrench_col + 4]
    reasons: list[tuple[str, slice | list[int] | None]] = [
        ("moves no flange pose (equivalent parameters of the chain)", None),
        ("absorbed by Z (robot/world): it moves the whole arm in the robot's frame", z_cols),
        ("absorbed by X" + (" and Y" if nb > 1 else "") + " (hand/eye): it moves only "
         "what the flange carries", x_cols),
        ("absorbed by X, Y and Z together" if not distortion else
         "absorbed by X, Y, Z and the tracker distortion together (e.g. a tracker scale "
         "and the arm's overall size)", slice(0, nx))]
    if wrench_col is not None:
        reasons[-1] = (reasons[-1][0] + " (with the wrench model)", slice(0, nx))
    if not nb:   # wrench rows only (force-sensor self-calibration): gravity sees rotations
        reasons = [
            (ZERO_WRENCH_REASON, None),
            ("absorbed by the base tilt: it tilts the whole arm in gravity", z_cols),
            ("absorbed by the sensor's rotation on the flange", x_cols),
            ("absorbed by the base tilt and the sensor's rotation together", slice(0, nx))]
    taken = np.zeros((len(names), 0))
    unident: list[Combination] = []
    for why, cols in reasons:
        M = Jk if cols is None else _residual_of(Jd[:, cols], Jk)
        basis = _complement(_null_basis(M, tol), taken)
        taken = np.concatenate([taken, basis], axis=1)
        for v in _echelon(basis).T:
            c = _combination(names, v / np.linalg.norm(v), 0.0, delta_s, vf)
            unident.append(Combination(c.terms, 0.0, c.estimate, float(np.sqrt(vf)), why,
                                       c.vector))
    return ident, weak, unident


def _compressed(Jd: np.ndarray) -> np.ndarray:
    """R (k, k) of the thin QR Jd = Q R of a tall Jd (m, k), else Jd itself. Everything here
    depends on Jd only through its columns' inner products (projections of columns onto
    others' span, singular values and right singular vectors), which R keeps, so the m rows
    are reduced to k once, in O(m k²): what follows costs nothing in the poses."""
    m, k = Jd.shape
    if m <= k:
        return Jd
    R: np.ndarray = np.linalg.qr(Jd, mode="r")  # type: ignore[assignment]
    return R


def _residual_of(M: np.ndarray, J: np.ndarray) -> np.ndarray:
    """J with its projection onto the column space of M removed."""
    Q, _ = np.linalg.qr(M)
    return J - Q @ (Q.T @ J)


def _null_basis(M: np.ndarray, tol: float) -> np.ndarray:
    """Orthonormal basis (k, r) of the null space of M (·, k), singular values ≤ tol."""
    _, sig, Vt = np.linalg.svd(M, full_matrices=True)
    rank = int(np.sum(sig > tol))
    return Vt[rank:].T


def _complement(basis: np.ndarray, taken: np.ndarray) -> np.ndarray:
    """An orthonormal basis of span(basis) with span(taken) (orthonormal) removed."""
    if basis.shape[1] == 0 or taken.shape[1] == 0:
        return basis
    rest = basis - taken @ (taken.T @ basis)
    U, sig, _ = np.linalg.svd(rest, full_matrices=False)
    return U[:, sig > 1e-6]


def _echelon(basis: np.ndarray) -> np.ndarray:
    """The same span in reduced column echelon form (each vector one leading parameter with
    coefficient 1, zero in the others' leading rows; pivots by magnitude)."""
    B = basis.copy()
    rows: list[int] = []
    for j in range(B.shape[1]):
        free = [i for i in range(B.shape[0]) if i not in rows]
        i = free[int(np.argmax(np.abs(B[free, j])))]
        B[:, j] /= B[i, j]
        for k in range(B.shape[1]):
            if k != j:
                B[:, k] -= B[i, k] * B[:, j]
        rows.append(i)
    return B


def _combination(names: list[str], v: np.ndarray, sigma: float, delta_s: np.ndarray,
                 vf: float) -> Combination:
    v = v if v[np.argmax(np.abs(v))] > 0 else -v
    order = np.argsort(-np.abs(v))
    terms = {names[j]: float(v[j]) for j in order if abs(v[j]) >= 0.05}
    return Combination(terms, sigma, float(v @ delta_s),
                       float(np.sqrt(vf / (sigma ** 2 + 1.0))), vector=v)
