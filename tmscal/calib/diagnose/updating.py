"""The partial re-registration (docs/lab-day.md, "Updates"): only the named blocks fitted,
refused (:class:`UpdateRefused`) when a second change is significant or the residuals stay
beyond the noise (:func:`update`); the updated calibration (:func:`updated`), its noise
model (:func:`noise_after`), the predicted coil-placement spread (:func:`placement_spread`),
and the poses each update needs (:func:`min_poses`). Poses 4×4 mm; residuals mm, deg."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ...errors import CalibrationError
from ...geometry import orthonormalize
from ..calibration import Applied, Calibration
from .decision import Diagnosis, _beyond_noise, _f_p, _hypotheses, _overlap, diagnose
from .fitting import Fit, _anchor, fit
from .model import ALLOWANCE, ALPHA, BLOCK_OF, UPDATES, Frames, NoiseModel, _apply, _moved, _xi

__all__ = ["UpdateRefused", "blocks_of_update", "min_poses", "update", "updated", "noise_after",
           "placement_spread"]


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
