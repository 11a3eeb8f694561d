"""Outlier poses: the robust rule ``tmscal solve`` applies to the per-pose errors.

A per-pose error (e_trans in mm or θ in degrees of E = (A X)⁻¹ Z N; docs/methods.md) is a
magnitude: positive and right-skewed, so a rule on the raw values (median + 3 MAD) flags
several clean poses in every few hundred. The rule therefore works on the logarithm:

    pose i is an outlier of a series v  ⇔  log v_i > median(log v) + K · 1.4826 · MAD(log v)

with K = 3 and MAD the median absolute deviation (1.4826 · MAD estimates a standard deviation
for normal data; the median-absolute-deviation rule of Leys et al. 2013, on the log scale). A
value below ``FLOOR`` (1e-6 mm or degrees) is never flagged: noise-free data has no outliers.
Each body's translation and rotation series is tested on its own; a pose is named once, with
the series that flagged it.

Leys C, Ley C, Klein O, Bernard P, Licata L (2013). Detecting outliers: do not use standard
deviation around the mean, use absolute deviation around the median. J. Experimental Social
Psychology 49(4):764–766.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["K", "FLOOR", "RULE", "outlier_threshold", "find_outliers"]

K = 3.0
FLOOR = 1e-6
RULE = ("log e > median(log e) + 3 · 1.4826 · MAD(log e), per body and per translation/"
        "rotation series (Leys et al. 2013 on the log scale)")

_SERIES = (("trans_mm", "translation", "mm"), ("rot_deg", "rotation", "deg"))


def outlier_threshold(values: ArrayLike, k: float = K) -> float:
    """The value above which a per-pose error is an outlier: exp(median(log v) + k · 1.4826 ·
    MAD(log v)), in the unit of ``values``; inf for fewer than 3 values above ``FLOOR``."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > FLOOR)]
    if len(v) < 3:
        return float("inf")
    lv = np.log(v)
    med = float(np.median(lv))
    mad = float(np.median(np.abs(lv - med)))
    return float(np.exp(med + k * 1.4826 * mad))


def find_outliers(residuals: dict[str, Any], k: float = K) -> list[dict[str, Any]]:
    """Outlier poses of ``solving.solve.pose_residuals`` output ({"index": [..], "<body>":
    {"trans_mm": [..], "rot_deg": [..]}}): one entry per flagged pose, in index order,
    {"index": session pose index, "flags": [{"body", "metric" ("translation"/"rotation"),
    "value", "threshold", "unit"}]}."""
    idx = list(residuals["index"])
    found: dict[int, list[dict[str, Any]]] = {}
    for body in ("marker", "probe"):
        if body not in residuals:
            continue
        for key, metric, unit in _SERIES:
            v = np.asarray(residuals[body][key], dtype=float)
            thr = outlier_threshold(v, k)
            for i in np.nonzero((v > thr) & (v > FLOOR))[0]:
                found.setdefault(int(idx[i]), []).append(
                    {"body": body, "metric": metric, "value": float(v[i]),
                     "threshold": thr, "unit": unit})
    return [{"index": i, "flags": found[i]} for i in sorted(found)]
