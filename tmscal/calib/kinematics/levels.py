"""The level of the kinematic fit chosen from held-out scores (:func:`choose_level`;
docs/kinematics.md, "The estimator"). Pure numerics on per-pose scores.

Each level ("none", "offsets", "full") is scored on the poses each fold held out by the
negative log-likelihood of their tracker poses under the model fitted without them, per pose
−2 ln p = r_iᵀ S_i⁻¹ r_i + ln det S_i (+ a constant): every residual component, rotations
included, weighted by the noise that level estimated (the noise is part of each level's
model: a level that leaves the arm's error in the residuals also inflates its noise, which
the log-determinant charges). The held-out translation error e_t (mm) is reported beside it
but does not choose: it is a sum of norms dominated by the tracker's and the robot's noise,
and on the mock rigs it preferred a level whose coil placement was 1.7× worse (issue 20).
A simpler level wins when the mean of its per-pose difference to the best is within one
standard error of that paired difference (the poses are the same for every level) and its
information criterion is lower.
"""

from __future__ import annotations

import numpy as np

__all__ = ["choose_level"]


def choose_level(heldout: dict[str, tuple[np.ndarray, np.ndarray] | None],
                 aic: dict[str, float], folds: int
                 ) -> tuple[str | None, str, dict[str, dict[str, float] | None]]:
    """(the chosen level or None when no level could be scored, the reason, the table)
    from ``heldout`` {level: (e_t per held-out pose mm, −2 ln p per held-out pose) or None},
    in the order simpler → richer, the levels' information criteria ``aic`` and the number
    of ``folds``. The table: {level: {"e_t_mm", "se_mm" (its standard error), "nll" (mean
    −2 ln p per pose), "nll_se", "folds"} or None}."""
    cv: dict[str, dict[str, float] | None] = {}
    for lv, h in heldout.items():
        if h is None:
            cv[lv] = None
            continue
        e, c = h
        cv[lv] = {"e_t_mm": float(e.mean()), "se_mm": float(e.std(ddof=1) / np.sqrt(len(e))),
                  "nll": float(c.mean()), "nll_se": float(c.std(ddof=1) / np.sqrt(len(c))),
                  "folds": float(folds)}
    scored = [lv for lv, h in heldout.items() if h is not None]
    if not scored:
        return None, "", cv
    best = min(scored, key=lambda lv: heldout[lv][1].mean())  # type: ignore[index]
    nll = {lv: heldout[lv][1] for lv in scored}  # type: ignore[index]
    reason = (f"held-out −2 ln p {cv[best]['nll']:.4g} per pose, the lowest of "  # type: ignore
              + ", ".join(f"{lv} {cv[lv]['nll']:.4g}" for lv in scored))  # type: ignore
    for lv in scored[:scored.index(best)]:  # simpler levels first
        d = nll[lv] - nll[best]
        se = float(d.std(ddof=1) / np.sqrt(len(d)))
        if float(d.mean()) <= se and aic[lv] < aic[best]:
            reason = (f"held-out −2 ln p {cv[lv]['nll']:.4g} per pose within one standard "  # type: ignore
                      f"error ({se:.3g}) of {best}'s {cv[best]['nll']:.4g}; the lower AIC "  # type: ignore
                      "decides")
            best = lv
            break
    return best, reason, cv
