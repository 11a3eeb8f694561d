"""Which hypothesis explains a session (docs/lab-day.md, "The rule"): each change tested
against "nothing changed" by the F test of the extra sum of squares (Bonferroni, family
level ``ALPHA``), the winner by AICc (Hurvich & Tsai 1989), the runner-up's evidence ratio,
and "unexplained" when the residuals stay beyond the noise or a second change is
significant (:func:`diagnose`, :class:`Diagnosis`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import chi2
from scipy.stats import f as f_dist

from .fitting import Fit, _anchor, fit
from .model import ALLOWANCE, ALPHA, BLOCK_OF, CHI2_LEVEL, HYPOTHESES, Frames, NoiseModel

__all__ = ["Diagnosis", "diagnose"]


def _f_p(small: Fit, big: Fit) -> float:
    """p-value of the F test of the extra sum of squares, ``big`` nesting ``small``."""
    dk = big.k - small.k
    if big.dof <= 0 or dk <= 0:
        return 1.0
    floor = 1e-10 * big.m  # whitened units: far below any noise, above rounding
    if small.rss <= floor:
        return 1.0  # nothing left to explain
    if big.rss <= floor:
        return 0.0  # the larger model explains what is left exactly
    F = max(small.rss - big.rss, 0.0) / dk / (big.rss / big.dof)
    return float(f_dist.sf(F, dk, big.dof))


def _beyond_noise(ft: Fit, allowance: float) -> bool:
    """The residuals beyond ``allowance``× the stored noise (χ² at CHI2_LEVEL)."""
    return ft.dof > 0 and ft.rss > allowance ** 2 * chi2.ppf(CHI2_LEVEL, ft.dof)


def _hypotheses(fr: Frames) -> list[str]:
    """The hypotheses these frames can test: with the probe all four rigid ones; marker
    only, the tracker and the coil (a marker moved on the coil and a coil re-seated are the
    same X change without the probe); the arm where joints and an arm model are known."""
    hs = ["tracker", "coil"] + (["marker", "coil_centre"] if "probe" in fr.N else [])
    if fr.fk is not None and fr.joints is not None:
        hs.append("arm")
    return hs


def _overlap(a: str, b: str) -> bool:
    return {a, b} in ({"coil", "x"}, {"coil", "y"}) or a == b


@dataclass
class Diagnosis:
    """What :func:`diagnose` decided: ``changed`` (``none``, a hypothesis, or
    ``unexplained``), the fits by hypothesis (``fits``, "none" included), their p-values
    against nothing changed, the ``pair`` of changes a second test found, notes."""

    changed: str
    fits: dict[str, Fit]
    p_values: dict[str, float]
    winner: str | None
    runner_up: str | None
    evidence_ratio: float | None
    pair: tuple[str, str] | None = None
    notes: list[str] = field(default_factory=list)
    alpha: float = ALPHA
    allowance: float = ALLOWANCE

    @property
    def label(self) -> str:
        """A phrase: "the tracker moved", "nothing changed", …"""
        return {"none": "nothing changed", "tracker": "the tracker moved",
                "coil": "the coil was re-seated on the flange",
                "marker": "the marker moved on the coil",
                "coil_centre": "the coil's centre changed (another coil?)",
                "arm": "the arm changed (a joint offset)",
                "unexplained": "none of the single changes explains the session"
                }[self.changed]

    def to_json(self) -> dict[str, Any]:
        """The ``diagnosis`` object of ``--json`` (mm, degrees)."""
        main = self.winner if self.winner in self.fits else None
        size = self.fits[main].size(BLOCK_OF[main]) if main and main != "none" else None
        alts = []
        for h, ft in sorted(self.fits.items(), key=lambda kv: kv[1].aicc):
            a: dict[str, Any] = {"changed": h, "aicc": ft.aicc, "noise_ratio": ft.noise_ratio,
                                 "p_value": self.p_values.get(h)}
            if h != "none":
                s = ft.size(BLOCK_OF[h])
                a.update(delta_mm=_num(s["mm"]), delta_deg=_num(s["deg"]))
            alts.append(a)
        return {"changed": self.changed, "label": self.label,
                "winner": self.winner,
                "delta_mm": _num(size["mm"]) if size else None,
                "delta_deg": _num(size["deg"]) if size else None,
                "sigma": ({"mm": _num(size["sigma_mm"]), "deg": _num(size["sigma_deg"])}
                          if size else None),
                **({"joint": size["joint"]} if size and "joint" in size else {}),
                "runner_up": self.runner_up, "evidence_ratio": _num(self.evidence_ratio),
                "pair": list(self.pair) if self.pair else None,
                "noise_ratio": (self.fits[main].noise_ratio if main else
                                self.fits["none"].noise_ratio),
                "alternatives": alts, "notes": list(self.notes),
                "test": {"rule": "F test against nothing changed (Bonferroni), AICc "
                                 "(Hurvich & Tsai 1989) among the significant; docs/lab-day.md",
                         "alpha": self.alpha, "allowance": self.allowance,
                         "chi2_level": CHI2_LEVEL}}


def _num(x: float | None) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def diagnose(fr: Frames, noise: NoiseModel, alpha: float = ALPHA,
             allowance: float = ALLOWANCE) -> Diagnosis:
    """Which single change explains the session (module docstring; docs/lab-day.md)."""
    hs = _hypotheses(fr)
    _anchor(fr, noise, [()] + [(BLOCK_OF[h],) for h in hs])
    none = fit(fr, noise)
    fits = {"none": none}
    notes: list[str] = []
    if "probe" not in fr.N:
        notes.append("marker only: a marker moved on the coil and a coil re-seated on the "
                     "flange are one X change without the probe (both reported as 'coil')")
    for h in hs:
        ft = fit(fr, noise, (BLOCK_OF[h],))
        if ft.rank_ok and ft.dof > 0:
            fits[h] = ft
        else:
            notes.append(f"{h}: not determined by these {fr.n} poses")
    p = {h: _f_p(none, ft) for h, ft in fits.items() if h != "none"}
    level = alpha / max(len(p), 1)
    sig = [h for h in p if p[h] < level]
    tie = {h: i for i, h in enumerate(HYPOTHESES)}

    def order(h: str) -> tuple[float, float, int]:
        f = fits[h]
        return (round(f.aicc, 6), f.rss, tie.get(h, -1))

    if not sig:
        winner = "none"
        changed = "unexplained" if _beyond_noise(none, allowance) else "none"
        if changed == "unexplained":
            notes.append(f"the residuals are {none.noise_ratio:.1f}× the calibration's noise "
                         f"(allowance {allowance:g}×) and no single change explains them")
        rest = sorted((h for h in fits if h != "none"), key=order)
    else:
        ranked = sorted(sig, key=order)
        winner = ranked[0]
        changed = winner
        rest = [h for h in sorted(fits, key=order) if h != winner]
    runner = rest[0] if rest else None
    ev = (float(np.exp(min((fits[runner].aicc - fits[winner].aicc) / 2, 700)))
          if runner else None)
    pair = None
    if changed not in ("none", "unexplained"):
        best = fits[winner]
        wb = BLOCK_OF[winner]
        extras = [h for h in hs if h != winner and not _overlap(BLOCK_OF[h], wb)]
        pvals = {}
        for h in extras:
            two = fit(fr, noise, (wb, BLOCK_OF[h]))
            if two.rank_ok and two.dof > 0:
                pvals[h] = _f_p(best, two)
        if pvals:
            h2 = min(pvals, key=pvals.__getitem__)
            if pvals[h2] < alpha / len(pvals):
                pair = (winner, h2)
                changed = "unexplained"
                notes.append(f"a second change on top of '{winner}' is significant: "
                             f"'{h2}' (p = {pvals[h2]:.2g})")
        if changed != "unexplained" and _beyond_noise(best, allowance):
            changed = "unexplained"
            notes.append(f"after '{winner}' the residuals are still {best.noise_ratio:.1f}× "
                         f"the calibration's noise (allowance {allowance:g}×)")
    ratio = fits[winner].noise_ratio
    if changed not in ("unexplained",) and ratio > 1.5:
        notes.append(f"today's residuals are {ratio:.1f}× the calibration's noise")
    return Diagnosis(changed, fits, p, winner, runner, ev, pair, notes, alpha, allowance)
