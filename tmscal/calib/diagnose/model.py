"""The model of a calibration held against a new session (docs/lab-day.md; the package
:mod:`tmscal.calib.diagnose` says how it is used): the hypotheses and their blocks, the
calibration's noise model (:class:`NoiseModel`), the frames of a session under a
calibration (:class:`Frames`, :func:`frames`), the per-pose residual r = [t(E) mm; rotation
vector of E deg] of E = (A X)⁻¹ Z N (:func:`residuals`), and the rigid changes Δ of each
block (their parametrisation, the frames moved by them, the closed-form starts, the
calibration's Jacobian). Frames and units: X = flange_from_marker, Y = flange_from_probe,
Z = base_from_tracker, A = base_from_flange, B = tracker_from_marker, C =
tracker_from_probe; 4×4 mm."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ...errors import CalibrationError
from ...geometry import make_pose, matrix_from_rotvec, orthonormalize, pose_mean, rotvec_from_matrix
from ..calibration import Applied, Calibration

__all__ = ["HYPOTHESES", "BLOCK_OF", "HYPOTHESIS_OF", "UPDATES", "ALPHA", "ALLOWANCE",
           "CHI2_LEVEL", "COMPONENTS", "RANK_TOL", "NoiseModel", "Frames", "frames", "residuals",
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
