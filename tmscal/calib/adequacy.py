"""Can a rigid hand/eye model explain a session? The adequacy rules of every solve
(docs/adequacy.md).

A calibration (X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm)
is held against the poses it was solved on (A = base_from_flange, B = tracker_from_marker,
C = tracker_from_probe) as the daily check does (:mod:`tmscal.calib.diagnose`): each pose and
body gives r = [t(E) mm; rotation vector of E deg], E = (A X)⁻¹ Z N, whitened by the
residual covariance Σ of the session itself. The noise model's scale comes from the
residuals, so residuals that are merely large (a noisy tracker) never make a warning; what
makes one is *structure* that a named cause explains and noise does not. Each cause is one
rule, a model nested in (or, for a mistake, as large as) the rigid one, with its statistic:

================  =====================================================================
cause             rule (statistic; p-value)
================  =====================================================================
``tool_moved``    a step in time: one rigid change of the tracker (Z), the coil (X and Y),
                  the marker (X) or the coil's centre (Y) from pose k on, fitted on each
                  side (linearised ``diagnose`` blocks); F of the extra sum of squares
                  (6, m − 12) against one change for all poses, Bonferroni over k and the
                  four blocks
``kinematics``    residuals that follow the joints: the kinematic estimate's held-out χ² per
                  pose (``calib.kinematics``, every level cross-validated under one noise)
                  of the rigid level against the best level with the arm's deviations;
                  one-sided z of the paired per-pose difference
``tracker``       a scale pattern: ml's tracker distortion models, forward F tests none →
                  scale → axis → affine (``ml.select_model``); the smallest p × 3
``inverted``      a mistake: the same closed-form solve on the tracker poses (or the robot
``metres``        poses) inverted, in metres (× 1000 makes mm), one pose late or early:
``late_frames``   the variance ratio F = RSS_t(as recorded) / RSS_t(corrected) of the
                  translation residuals (mm²) against F(m − k, m − k)
``repeated``      a pose whose tracker reading is bit for bit the previous pose's while the
                  robot moved (a frame the tracker did not refresh): no noise repeats a
                  reading exactly
================  =====================================================================

The decision (:func:`decide`): every p-value is multiplied by the number of rules run
(Bonferroni, family level ``ALPHA``); "inadequate" when any is below ``ALPHA``; the likely
cause is the first of those in the order of ``CAUSES``: a mistake before a structure (a
mistake makes every structure rule fire), a step before the joints and the tracker; when
both the joints and the tracker fire (an affine tracker distortion absorbs much of an arm's
error over a small workspace), the one whose model lowers the residual variance more (the
larger ``ratio``: held out for the joints, in-sample for the tracker). ``chi2_per_dof``
is the rigid model's residual variance in units of the noise the likely cause's model
leaves (the variance ratio; ≈ 1 when adequate) and ``p_value`` that cause's adjusted
p-value (adequate: the smallest). Measured error rates: ``benchmarks/adequacy.py``
(docs/adequacy.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.stats import f as f_dist

from ..errors import CalibrationError
from . import diagnose as dg
from .diagnose.model import _apply, _xi

__all__ = ["ALPHA", "CAUSES", "MISTAKES", "Rule", "Adequacy", "subset", "noise_of",
           "step_rule", "kinematics_rule", "distortion_rule", "mistake_rule", "repeated_rule",
           "mistaken", "decide"]

#: family-wise level of a false warning on a session the rigid model explains
ALPHA = 0.01
#: the causes, in the order that breaks a tie of p-values (mistakes first)
CAUSES = ("repeated", "inverted_tracker", "inverted_robot", "metres_tracker", "metres_robot",
          "late_frames", "early_frames", "tool_moved", "kinematics", "tracker")
#: the mistakes tested by correcting the data and solving again: name → what was wrong
MISTAKES = {
    "inverted_tracker": "the tracker poses are inverted (marker_from_tracker, not "
                        "tracker_from_marker)",
    "inverted_robot": "the robot poses are inverted (flange_from_base, not base_from_flange)",
    "metres_tracker": "the tracker poses are in metres, not millimetres",
    "metres_robot": "the robot poses are in metres, not millimetres",
    "late_frames": "each tracker reading is the previous pose's (the tracker frames lag the "
                   "robot by one pose: read before the robot settled)",
    "early_frames": "each tracker reading is the next pose's (the poses' readings are "
                    "shifted by one)",
}
#: shortest segment on either side of a step
MIN_SEGMENT = 3


@dataclass(frozen=True)
class Rule:
    """One rule's outcome: ``cause`` (``CAUSES``), the ``statistic`` (an F value) on
    ``dof`` degrees of freedom, its ``p_value`` and the ``p_adjusted`` one (× the
    multiplicity inside the rule, then × the rules in the family, by :func:`decide`), the
    ``ratio`` of variances (residuals as solved over residuals under the cause's model),
    ``detail`` (plain types: what the rule found, e.g. the pose of a step, mm, deg)."""

    cause: str
    statistic: float
    dof: tuple[int, int]
    p_value: float
    ratio: float
    multiplicity: int = 1
    detail: dict[str, Any] = field(default_factory=dict)
    p_adjusted: float = 1.0

    def to_json(self) -> dict[str, Any]:
        return {"cause": self.cause, "statistic": _num(self.statistic),
                "dof": list(self.dof), "p_value": float(self.p_value),
                "p_adjusted": float(self.p_adjusted), "ratio": _num(self.ratio),
                "multiplicity": int(self.multiplicity), **self.detail}


@dataclass(frozen=True)
class Adequacy:
    """The verdict of :func:`decide`: ``verdict`` ("adequate" or "inadequate"),
    ``likely_cause`` (a ``CAUSES`` name, None when adequate), ``chi2_per_dof`` and
    ``p_value`` (module docstring), every ``rules`` outcome, ``notes`` (rules that could not
    run and why), ``alpha``."""

    verdict: str
    likely_cause: str | None
    chi2_per_dof: float
    p_value: float
    rules: list[Rule]
    notes: list[str] = field(default_factory=list)
    alpha: float = ALPHA

    @property
    def cause_rule(self) -> Rule | None:
        """The likely cause's rule (None when adequate)."""
        return next((r for r in self.rules if r.cause == self.likely_cause), None)

    def to_json(self) -> dict[str, Any]:
        """Plain types: {chi2_per_dof, p_value, verdict, likely_cause, rules, notes, test}."""
        return {"chi2_per_dof": _num(self.chi2_per_dof), "p_value": float(self.p_value),
                "verdict": self.verdict, "likely_cause": self.likely_cause,
                "rules": [r.to_json() for r in self.rules], "notes": list(self.notes),
                "test": {"rule": "one rule per cause, Bonferroni over the rules; "
                                 "docs/adequacy.md", "alpha": self.alpha}}


def _num(x: float | None) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def subset(fr: dg.Frames, sl: slice) -> dg.Frames:
    """The frames of poses ``sl`` (the same calibration, joints and forward kinematics)."""
    return dg.Frames(fr.A[sl], {b: N[sl] for b, N in fr.N.items()}, fr.X, fr.Z,
                     None if fr.joints is None else fr.joints[sl], fr.fk,
                     None if fr.indices is None else list(fr.indices)[sl], fr.centre)


def noise_of(fr: dg.Frames) -> dg.NoiseModel:
    """The session's own residual covariance (``diagnose.noise_from_residuals``, 6
    parameters per solved transform), without the calibration's uncertainty: its shape
    weighs the components, its scale is profiled out by every F test."""
    nm = dg.noise_from_residuals(dg.residuals(fr), fr.bodies, 6 * (len(fr.bodies) + 1),
                                 "the session's residuals")
    return replace(nm, cal_cov=None, cal_blocks=())


def _f_sf(F: float, d1: int, d2: int) -> float:
    if d1 <= 0 or d2 <= 0 or not np.isfinite(F):
        return 1.0 if not np.isfinite(F) or F <= 0 else 0.0
    return float(f_dist.sf(F, d1, d2))


def _pose_jacobians(fr: dg.Frames, noise: dg.NoiseModel, block: str
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per pose the whitened residual w_i (n, q) and its Jacobian J_i (n, q, 6) with respect
    to a change of ``block`` (``diagnose``'s parametrisation), by forward differences."""
    Sp = noise.for_bodies(fr.bodies).cov
    Wp = np.linalg.inv(np.linalg.cholesky(Sp))
    w0 = dg.residuals(fr) @ Wp.T
    h = 1e-6
    J = np.empty(w0.shape + (6,))
    for j in range(6):
        p = np.zeros(6)
        p[j] = h
        J[:, :, j] = (dg.residuals(_apply(fr, (block,), {block: p})) @ Wp.T - w0) / h
    return w0, J


def _ls(G: np.ndarray, g: np.ndarray, s: float) -> tuple[float, np.ndarray, bool]:
    """RSS and step of the linear least squares min ‖w + J p‖² from its sums G = JᵀJ,
    g = Jᵀw, s = wᵀw; whether G is well conditioned."""
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))  # column scaling (mm and rad differ)
    Gs = G / d[:, None] / d[None, :]
    sv = np.linalg.svd(Gs, compute_uv=False)
    # G = JᵀJ: its singular values are J's squared; J's condition is diagnose's criterion
    lo, hi = float(sv[-1]), float(sv[0])
    ok = bool(np.sqrt(max(lo, 0.0)) > dg.RANK_TOL * np.sqrt(max(hi, 1e-300)))
    p = -np.linalg.lstsq(Gs, g / d, rcond=None)[0] / d
    return max(float(s + g @ p), 0.0), p, ok


def _exact_step(fr: dg.Frames, noise: dg.NoiseModel, block: str, k: int
                ) -> tuple[float, np.ndarray, float, float] | None:
    """(F, the change between the sides [v mm; ω rad], RSS of one change for all, RSS of one
    per side) of ``block`` stepping at k, fitted by ``diagnose.fit``; None if undetermined."""
    base = dg.fit(fr, noise, (block,))
    sides = [dg.fit(subset(fr, sl), noise, (block,)) for sl in (slice(0, k), slice(k, fr.n))]
    if not (base.rank_ok and all(f.rank_ok for f in sides)):
        return None
    m = fr.n * 6 * len(fr.bodies)
    rss = sides[0].rss + sides[1].rss
    F = max(base.rss - rss, 0.0) / 6 / max(rss / (m - 12), 1e-300)
    D = np.linalg.inv(sides[0].delta(block)) @ sides[1].delta(block)
    return float(F), _xi(D), base.rss, rss


def step_rule(fr: dg.Frames, noise: dg.NoiseModel, min_segment: int = MIN_SEGMENT
              ) -> Rule | None:
    """A tool moved during the session (module docstring): every step position k with
    ``min_segment`` poses on each side, each block's change fitted on each side by the
    linearised least squares of the whitened residuals (one Jacobian per pose and block,
    cumulative sums: every k costs the same as one fit), then at the k found each block
    fitted exactly (``diagnose.fit`` on each side); None when the session is too short.
    ``detail``: ``pose`` (the first pose after the step: the session index when
    ``fr.indices`` has them), ``position`` (its place among the usable poses), ``moved``
    (``diagnose`` hypothesis), ``delta_mm``, ``delta_deg`` (the change between the sides),
    ``runner_up`` (the next block's hypothesis and its largest F: on a plan of small
    rotations a tracker move and a coil re-seat are close)."""
    n = fr.n
    if n < 2 * min_segment + 1:
        return None
    blocks = ["z", "coil"] + (["x", "y"] if "probe" in fr.N else [])
    q = 6 * len(fr.bodies)
    m = n * q
    ks = range(min_segment, n - min_segment + 1)
    best: tuple[float, str, int, np.ndarray, float, float] | None = None
    per_block: dict[str, float] = {}
    for b in blocks:
        w, J = _pose_jacobians(fr, noise, b)
        Gi = np.einsum("nqa,nqb->nab", J, J)
        gi = np.einsum("nqa,nq->na", J, w)
        si = np.einsum("nq,nq->n", w, w)
        G, g, S = np.cumsum(Gi, axis=0), np.cumsum(gi, axis=0), np.cumsum(si)
        rss0, _, ok0 = _ls(G[-1], g[-1], S[-1])
        if not ok0:
            continue
        for k in ks:
            r1, p1, ok1 = _ls(G[k - 1], g[k - 1], S[k - 1])
            r2, p2, ok2 = _ls(G[-1] - G[k - 1], g[-1] - g[k - 1], S[-1] - S[k - 1])
            if not (ok1 and ok2):
                continue
            rss = r1 + r2
            F = max(rss0 - rss, 0.0) / 6 / max(rss / (m - 12), 1e-300)
            per_block[b] = max(per_block.get(b, 0.0), F)
            if best is None or F > best[0]:
                best = (F, b, k, p2 - p1, rss0, rss)
    if best is None:
        return None
    F, b, k, dp, rss0, rss1 = best
    exact = {}  # at the step found, every block fitted exactly (a tracker turned about its
    for bb in blocks:  # own origin, 1.5 m away, is far from linear at the poses)
        got = _exact_step(fr, noise, bb, k)
        if got is not None:
            exact[bb] = got
    if exact:
        b = max(exact, key=lambda bb: exact[bb][0])
        F, dp, rss0, rss1 = exact[b]
        per_block = {bb: v[0] for bb, v in exact.items()}
    ratio = (rss0 / (m - 6)) / max(rss1 / (m - 12), 1e-300)
    pose = int(fr.indices[k]) if fr.indices is not None else int(k)
    others = sorted((v, h) for h, v in per_block.items() if h != b)
    runner = None if not others else {"moved": dg.HYPOTHESIS_OF[others[-1][1]],
                                      "statistic": float(others[-1][0])}
    return Rule("tool_moved", float(F), (6, m - 12), _f_sf(F, 6, m - 12), float(ratio),
                multiplicity=len(ks) * len(blocks),
                detail={"pose": pose, "position": int(k), "moved": dg.HYPOTHESIS_OF[b],
                        "delta_mm": float(np.linalg.norm(dp[:3])),
                        "delta_deg": float(np.degrees(np.linalg.norm(dp[3:]))),
                        "runner_up": runner})


def kinematics_rule(cv: dict[str, Any]) -> Rule | None:
    """Residuals that follow the joints: the kinematic estimate's held-out table (``cv`` of
    ``calib.kinematics``' level choice: {level: {"chi2", "chi2_se", …}}, each level's mean
    held-out χ² per pose under one noise) — the rigid level "none" against the best level
    with the arm's deviations, z = mean / SE of the per-pose difference of their held-out
    χ² (``gain_vs_none``; the same poses held out for both; without it the unpaired
    (χ²_none − χ²_best) / √(se_none² + se_best²), conservative), one-sided; × the levels
    compared. ``ratio``: χ²_none / χ²_best. None without "none" and another scored level."""
    rows = {k: v for k, v in (cv or {}).items() if isinstance(v, dict) and "chi2" in v}
    if "none" not in rows or len(rows) < 2:
        return None
    others = {k: v for k, v in rows.items() if k != "none"}
    best = min(others, key=lambda k: others[k]["chi2"])
    c0, c1 = float(rows["none"]["chi2"]), float(others[best]["chi2"])
    b = others[best]
    if "gain_vs_none" in b and "gain_vs_none_se" in b:  # paired over the held-out poses
        gain, se = float(b["gain_vs_none"]), float(b["gain_vs_none_se"])
    else:
        gain = c0 - c1
        se = float(np.hypot(rows["none"].get("chi2_se", 0.0), b.get("chi2_se", 0.0)))
    z = gain / se if se > 0 else (np.inf if gain > 0 else 0.0)
    from scipy.stats import norm

    return Rule("kinematics", float(z), (0, 0), float(norm.sf(z)), c0 / max(c1, 1e-300),
                multiplicity=len(others),
                detail={"level": best, "heldout_chi2_rigid": c0, "heldout_chi2_arm": c1})


def distortion_rule(p_values: dict[str, float], ratio: float = float("nan")) -> Rule | None:
    """A scale pattern (tracker distortion): ml's forward tests' p-values by model
    (``Calibration.extra["lrt"]`` of an ml solve with ``distortion="auto"``), the smallest
    taken, × the number of models tested; ``ratio`` the variance ratio of the residuals
    without and with the distortion when known. None when no distortion model was tested."""
    tested = {k: float(v) for k, v in p_values.items() if k != "none"}
    if not tested:
        return None
    model = min(tested, key=tested.__getitem__)
    return Rule("tracker", float("nan"), (0, 0), tested[model], float(ratio),
                multiplicity=len(tested), detail={"model": model})


def mistaken(name: str, A: np.ndarray, B: np.ndarray, C: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The poses (n, 4, 4) mm corrected for mistake ``name`` (``MISTAKES``): inverted poses
    inverted back, metres multiplied by 1000, each reading paired with the pose one later
    or earlier (one pose dropped)."""
    inv = np.linalg.inv
    if name == "inverted_tracker":
        return A, inv(B), None if C is None else inv(C)
    if name == "inverted_robot":
        return inv(A), B, C
    if name in ("metres_tracker", "metres_robot"):
        def scaled(T: np.ndarray, f: float) -> np.ndarray:
            T = T.copy()
            T[:, :3, 3] *= f
            return T
        if name == "metres_tracker":
            return A, scaled(B, 1000.0), None if C is None else scaled(C, 1000.0)
        return scaled(A, 1000.0), B, C
    if name == "late_frames":  # reading i belongs to pose i − 1: pair A[i−1] with B[i]
        return A[:-1], B[1:], None if C is None else C[1:]
    if name == "early_frames":
        return A[1:], B[:-1], None if C is None else C[:-1]
    raise CalibrationError(f"unknown mistake {name!r}; expected one of {', '.join(MISTAKES)}")


def _rss_t(solver: Callable[..., Any], A: np.ndarray, B: np.ndarray, C: np.ndarray | None
           ) -> tuple[float, int] | None:
    """Σ‖t(E)‖² (mm²) over poses and bodies of the rigid solve of (A, B, C), and the count
    of translation residuals; None when the solve fails."""
    try:
        cal = solver(A, B, C)
        fr = dg.frames(cal, A, B, C)
    except (CalibrationError, np.linalg.LinAlgError, ValueError):
        return None
    r = dg.residuals(fr)
    if not np.all(np.isfinite(r)):
        return None
    t = np.concatenate([r[:, 6 * i:6 * i + 3] for i in range(len(fr.bodies))], axis=1)
    return float(np.sum(t ** 2)), int(t.size)


def mistake_rule(name: str, A: np.ndarray, B: np.ndarray, C: np.ndarray | None,
                 solver: Callable[..., Any],
                 as_solved: tuple[float, int] | None = None) -> Rule | None:
    """Mistake ``name`` tested by correcting it: the rigid ``solver`` ((A, B, C) →
    Calibration, e.g. QR36 with orthonormal matrices) on the poses as recorded and as
    corrected (:func:`mistaken`); F = RSS_t(as recorded)/(m − k) over RSS_t(corrected)/(m'
    − k), k = 6 per solved transform per translation component set. ``as_solved``: the
    first RSS when already computed. None when either solve fails."""
    a = as_solved if as_solved is not None else _rss_t(solver, A, B, C)
    A2, B2, C2 = mistaken(name, A, B, C)
    b = _rss_t(solver, A2, B2, C2)
    if a is None or b is None:
        return None
    k = 3 * (2 + (C is not None))  # translations of X, Z (and Y)
    d1, d2 = a[1] - k, b[1] - k
    if d1 <= 0 or d2 <= 0:
        return None
    F = (a[0] / d1) / max(b[0] / d2, 1e-300)
    return Rule(name, float(F), (d1, d2), _f_sf(F, d1, d2), float(F))


def repeated_rule(A: np.ndarray, B: np.ndarray, indices: Sequence[int] | None = None,
                  moved_mm: float = 1e-3) -> Rule:
    """Poses whose tracker reading B (4×4 mm) equals the previous pose's to rounding
    (1e-9 mm) while the robot's flange moved more than ``moved_mm``; p = 0 when any, else
    1. ``detail``: ``poses`` [(pose, the pose it repeats)], session indices when given."""
    idx = list(range(len(A))) if indices is None else [int(i) for i in indices]
    hits = []
    for i in range(1, len(A)):
        same = np.max(np.abs(B[i] - B[i - 1])) < 1e-9 * max(1.0, float(np.max(np.abs(B[i]))))
        moved = np.linalg.norm(A[i][:3, 3] - A[i - 1][:3, 3]) > moved_mm
        if same and moved:
            hits.append([idx[i], idx[i - 1]])
    n = max(len(A) - 1, 1)
    return Rule("repeated", float(len(hits)), (n, 0), 0.0 if hits else 1.0,
                float("nan"), detail={"poses": hits})


def decide(rules: Sequence[Rule | None], notes: Sequence[str] = (), alpha: float = ALPHA
           ) -> Adequacy:
    """The verdict (module docstring) from the rules that ran (None: not run)."""
    ran = [r for r in rules if r is not None]
    fam = max(len(ran), 1)
    adj = [replace(r, p_adjusted=float(min(1.0, r.p_value * r.multiplicity * fam)))
           for r in ran]
    order = {c: i for i, c in enumerate(CAUSES)}
    ranked = sorted(adj, key=lambda r: (r.p_adjusted, order.get(r.cause, len(order))))
    fired = sorted((r for r in ranked if r.p_adjusted < alpha),
                   key=lambda r: order.get(r.cause, len(order)))
    by = {r.cause: r for r in fired}
    if fired and fired[0].cause == "kinematics" and "tracker" in by:
        k, t = by["kinematics"], by["tracker"]
        if np.isfinite(t.ratio) and (not np.isfinite(k.ratio) or t.ratio > k.ratio):
            fired.remove(t)
            fired.insert(0, t)
    top = fired[0] if fired else (ranked[0] if ranked else None)
    ratio = float("nan") if top is None else top.ratio
    return Adequacy("inadequate" if fired else "adequate",
                    fired[0].cause if fired else None, float(ratio),
                    1.0 if top is None else top.p_adjusted, adj, list(notes), alpha)
