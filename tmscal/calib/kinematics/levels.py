"""The levels of the kinematic fit: what each estimates (:func:`level_parameters`), the prior
on the deviations (:class:`Tolerances`), and the level chosen from held-out scores
(:func:`choose_level`; docs/kinematics.md, "The estimator"). Pure numerics.

Each level ("none", "offsets", "full") is scored on the poses each fold held out by the χ² of
their tracker poses' residuals under the model fitted without them (every residual
component, rotations included), whitened by ONE noise for every level: the one the richest
level estimated, whose residuals the arm's error inflates least (a level's own noise would
make each level's χ² about its degrees of freedom, whatever its error). It is ``ml``'s
weighted error measured on poses the fit did not see. The held-out translation error e_t
(mm) is reported beside it but does not choose: a sum of norms dominated by the tracker's and
the robot's noise, it chose `offsets` on the VS-060 mock rig of seed 1 where full placed the
coil 1.7× better (issue 20). A simpler level wins when the mean of its per-pose difference
to the best is within one standard error of that paired difference (the poses are the same
for every level) and its information criterion is lower.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import CalibrationError
from .jacobian import parallel_joints
from .model import Arm, deviation_units

__all__ = ["LEVELS", "Tolerances", "prior_sigmas", "level_parameters", "choose_level"]

LEVELS = ("none", "offsets", "full")


@dataclass(frozen=True)
class Tolerances:
    """The prior: each deviation ~ N(0, τ²) with τ = ``length_mm`` for d, a (mm) and
    ``angle_deg`` for θ0, α, β (degrees here, rad inside). The defaults are the assumption
    of docs/kinematics.md for an arm without a per-robot factory calibration."""

    length_mm: float = 0.5
    angle_deg: float = 0.1

    def __post_init__(self) -> None:
        for k in ("length_mm", "angle_deg"):
            v = getattr(self, k)
            if not (isinstance(v, int | float) and np.isfinite(v) and v > 0):
                raise CalibrationError(f"kinematics: tolerance {k} must be a finite number > 0, "
                                       f"got {v!r}")


def prior_sigmas(names: list[str], tol: Tolerances) -> np.ndarray:
    """τ per parameter (mm or rad)."""
    return np.array([tol.length_mm if u == "mm" else np.radians(tol.angle_deg)
                     for u in deviation_units(names)])


def level_parameters(chain: Arm, level: str) -> list[str]:
    """The deviations a level estimates, in the chain's order."""
    n = chain.n_joints
    if level == "none":
        return []
    if level == "offsets":
        return [f"theta0_{i}" for i in range(1, n + 1)]
    if level == "full":
        par = set(parallel_joints(chain))
        out = []
        for i in range(1, n + 1):
            out += [f"theta0_{i}", f"d_{i}", f"a_{i}", f"alpha_{i}"]
            if i in par:
                out.append(f"beta_{i}")
        return out
    raise CalibrationError(f"kinematics: unknown level {level!r}; expected auto, "
                           f"{', '.join(LEVELS)}")


def choose_level(heldout: dict[str, tuple[np.ndarray, np.ndarray] | None],
                 aic: dict[str, float], folds: int
                 ) -> tuple[str | None, str, dict[str, dict[str, float] | None]]:
    """(the chosen level or None when no level could be scored, the reason, the table)
    from ``heldout`` {level: (e_t per held-out pose mm, whitened χ² per held-out pose) or
    None}, in the order simpler → richer, the levels' information criteria ``aic`` and the
    number of ``folds``. The table: {level: {"e_t_mm", "se_mm" (its standard error), "chi2"
    (mean χ² per pose), "chi2_se", "folds", and beside "none" "gain_vs_none" (the mean over
    poses of "none"'s held-out χ² minus this level's, the same poses) and its standard error
    "gain_vs_none_se"} or None}."""
    def se(x: np.ndarray) -> float:
        return float(x.std(ddof=1) / np.sqrt(len(x)))

    scored = {lv: h for lv, h in heldout.items() if h is not None}
    cv: dict[str, dict[str, float] | None] = {lv: None for lv in heldout}
    for lv, (e, c) in scored.items():
        cv[lv] = {"e_t_mm": float(e.mean()), "se_mm": se(e), "chi2": float(c.mean()),
                  "chi2_se": se(c), "folds": float(folds)}
    if not scored:
        return None, "", cv
    chi2 = {lv: h[1] for lv, h in scored.items()}
    if "none" in chi2:  # the paired per-pose gain over the rigid model (the adequacy rule)
        for lv, c in chi2.items():
            if lv != "none" and len(c) == len(chi2["none"]) and len(c) > 1:
                d = chi2["none"] - c
                cv[lv]["gain_vs_none"] = float(d.mean())  # type: ignore[index]
                cv[lv]["gain_vs_none_se"] = se(d)  # type: ignore[index]
    best = min(chi2, key=lambda lv: float(chi2[lv].mean()))
    reason = (f"held-out χ² {chi2[best].mean():.4g} per pose, the lowest of "
              + ", ".join(f"{lv} {c.mean():.4g}" for lv, c in chi2.items()))
    order = list(chi2)
    for lv in order[:order.index(best)]:  # simpler levels first
        d = chi2[lv] - chi2[best]
        if float(d.mean()) <= se(d) and aic[lv] < aic[best]:
            reason = (f"held-out χ² {chi2[lv].mean():.4g} per pose within one standard "
                      f"error ({se(d):.3g}) of {best}'s {chi2[best].mean():.4g}; the lower AIC "
                      "decides")
            best = lv
            break
    return best, reason, cv
