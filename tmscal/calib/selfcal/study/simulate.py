"""The simulation study of force-torque self-calibration (Joubair, Zhao, Bigras and Bonev 2016,
section 5) on a serial arm or on the paper's own MedRUE (:mod:`.medrue`). Pure numerics, no I/O;
docs/selfcal.md ("Simulation study").

The protocol:

1. a candidate pool of configurations drawn uniformly within the joint limits (the paper:
   40,000 over the workspace; MedRUE: those its five-bars can reach, :meth:`MedRUE.reachable`);
2. the identification Jacobian of the nominal model over the pool, rows divided by the
   channel noise; the identifiable parameters (zero columns out, then one dependent column
   at a time, :func:`~tmscal.calib.selfcal.identify.identifiable`);
3. a "true" arm: the nominal one with uniform errors of ±2 mm on lengths and ±1° on angles —
   ``errors="all"`` (the default): on every geometric parameter (every length and angle,
   the base and sensor mounting included); ``errors="seen"``: on every parameter the gravity
   wrench sees, alone or in a combination (the identifiable ones and those confounded with
   them); ``errors="paper"``: on exactly the columns the identification keeps, as the paper's
   Table 1 does — the protocol whose noise-free fit is exact by construction, kept to compare
   with the paper and not a figure a lab gets;
4. 100 configurations chosen by O1 (DETMAX: maximising det(JᵀJ) is maximising O1 at a fixed
   count) from the pool; their wrenches from the true arm plus noise of ±1 N and ±0.2 N·m;
5. identification from the nominal start, and its answer made independent of the columns it
   kept (:func:`~tmscal.calib.selfcal.study.compare.canonical`: of the models with the fitted
   wrenches, the one with the smallest deviation from the nominal in units of ±2 mm / ±1°);
   validation on the rest of the pool: the TCP position error (mm, world frame, the flange
   origin unless ``tcp_mm``) between the true arm and the nominal one (before) and the
   identified one (after), mean, max and SD — raw, and after a hand/eye calibration absorbs
   what it can (:func:`~tmscal.calib.selfcal.study.compare.absorbed_errors`: the best rigid base
   transform and TCP offset; what a TMS rig's X, Y, Z would take up);
6. the index comparison (the paper's Table 4): the same with the configurations chosen
   greedily by each of O1…O5, by DETMAX and at random.

No "floor" is reported: the true arm is always among the models consistent with the wrenches,
so no bound below the error after follows from the wrenches alone.

The noise: the paper generates it "normally distributed within ±1 N", 100 measurements per
configuration; here each reading is normal with σ = bound/3 (±1 N is 3σ), drawn again beyond
the bound, the ``samples`` readings of a configuration (default 100) are averaged, and the fit
weights rows by σ (that of one reading: the averaged readings' spread is σ/√samples, so
the reduced χ² is about 1/samples).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..design import INDICES, candidate_pool, detmax, information, observability, scale_columns
from ..design import select_by_index as _select_by_index
from ..identify import ZERO_REASON, error_stats, identifiable, identify, position_errors
from ..model import NOMINAL, jacobian, perturb, wrench
from .compare import absorbed_errors, canonical
from .medrue import MEDRUE

__all__ = ["PAPER", "SimulationResult", "simulate", "wrench_noise", "SELECTIONS", "stages",
           "STUDY_ARMS", "ERRORS"]

#: the paper's figures (Joubair et al. 2016): parameter errors, wrench noise bounds, design
#: size, pool size, its result in the target workspace (mean, max before → after, mm) and its
#: count of identifiable parameters (46 in its Table 1, 17 of them starred non-identifiable)
PAPER = {"length_mm": 2.0, "angle_deg": 1.0, "force_n": 1.0, "torque_nm": 0.2, "k": 100,
         "pool": 40000, "before_mean_mm": 8.9135, "after_mean_mm": 0.2771,
         "before_max_mm": 12.0, "after_max_mm": 0.320, "identifiable": 29, "parameters": 46}

#: the prior of :func:`~tmscal.calib.selfcal.study.compare.canonical`: the standard deviation of
#: the protocol's uniform ±2 mm / ±1° errors (half-width / √3)
PRIOR = {"length_mm": PAPER["length_mm"] / np.sqrt(3.0),
         "angle_deg": PAPER["angle_deg"] / np.sqrt(3.0)}
#: the arms of the study: every registered serial arm (``model.NOMINAL``) and the paper's
#: MedRUE (``medrue.MEDRUE``, dimensions assumed)
STUDY_ARMS: dict[str, Any] = {**NOMINAL, "medrue": MEDRUE}
#: the error protocols (module docstring), the honest one first
ERRORS = ("all", "seen", "paper")

#: the selections of the index comparison, in the order reported
SELECTIONS = ("detmax",) + INDICES + ("random",)

Progress = Callable[[str], None]


@dataclass
class SimulationResult:
    """What :func:`simulate` found. Position errors in mm (TCP, world frame), each a dict
    {mean_mm, max_mm, sd_mm} over the validation configurations.

    ``identifiable``: the identifiable parameter names; ``removed``: [(name, reason)];
    ``in_error``: the parameters given errors; ``before`` / ``after``: nominal / identified
    (the DETMAX design, its canonical answer, pooled over the noise draws) against the true
    arm; ``before_absorbed`` / ``after_absorbed``: the same after a hand/eye calibration
    absorbs a rigid base transform and a TCP offset; ``indices``: per selection
    (``SELECTIONS``) {"after", "after_absorbed": stats pooled over the trials,
    "after_mean_mm_per_trial", "observability": O1…O5 of its design, "log_det":
    log det(JᵀJ)}; ``fit``: iterations, converged, reduced χ² of the DETMAX fit;
    ``settings``: the inputs."""

    settings: dict[str, Any]
    identifiable: list[str]
    removed: list[tuple[str, str]]
    in_error: list[str]
    before: dict[str, float]
    after: dict[str, float]
    before_absorbed: dict[str, float]
    after_absorbed: dict[str, float]
    indices: dict[str, dict[str, Any]] = field(default_factory=dict)
    fit: dict[str, Any] = field(default_factory=dict)

    @property
    def parameters(self) -> int:
        """The number of parameters of the arm's model."""
        return len(self.identifiable) + len(self.removed)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types."""
        return {"settings": self.settings, "identifiable": self.identifiable,
                "removed": [{"name": n, "reason": r} for n, r in self.removed],
                "in_error": self.in_error, "before": self.before, "after": self.after,
                "before_absorbed": self.before_absorbed, "after_absorbed": self.after_absorbed,
                "indices": self.indices, "fit": self.fit}


def wrench_noise(rng: np.random.Generator, m: int, force_n: float, torque_nm: float,
                 samples: int = 1) -> np.ndarray:
    """(m, 6) wrench noise [N ×3, N·m ×3]: the mean of ``samples`` readings, each channel
    normal with σ = bound/3 and drawn again beyond ±bound (the paper's "within ±1 N")."""
    bound = np.array([force_n] * 3 + [torque_nm] * 3)
    x = rng.normal(size=(samples, m, 6)) / 3.0
    bad = np.abs(x) > 1.0
    while bad.any():
        x[bad] = rng.normal(size=int(bad.sum())) / 3.0
        bad = np.abs(x) > 1.0
    return x.mean(axis=0) * bound


def _quiet(_stage: str) -> None:
    return None


def errors_on(model: Any, ident: Any, errors: str) -> list[str]:
    """The parameters a protocol puts errors on (module docstring), in the model's order:
    "paper" the kept columns, "seen" every column that is not zero, "all" every length and
    angle. Weight and bias (N, N·m) never carry one (``perturb`` leaves them)."""
    names = model.parameter_names()
    if errors == "paper":
        chosen = set(ident.kept)
    elif errors == "seen":
        chosen = set(names) - {n for n, r in ident.removed if r == ZERO_REASON}
    else:
        chosen = set(names)
    return [n for n, u in zip(names, model.parameter_units(), strict=True)
            if n in chosen and u in ("mm", "rad")]


@dataclass
class _Study:
    """The shared state of one study: the nominal and true arms, the pool and its Jacobian
    blocks on the identifiable columns."""

    nominal: Any
    true: Any
    q: np.ndarray
    blocks: np.ndarray
    keep: list[str]
    sigma: np.ndarray
    rng: np.random.Generator
    samples: int
    tcp: np.ndarray

    def fit(self, sel: np.ndarray) -> tuple[Any, Any]:
        """Measure the configurations ``sel`` on the true arm (plus noise), identify, and
        return (the fit, its canonical model)."""
        q = self.q[sel]
        w = wrench(self.true, q) + wrench_noise(self.rng, len(q), 3 * self.sigma[0],
                                                3 * self.sigma[3], self.samples)
        fit = identify(self.nominal, q, w, self.sigma, self.keep)
        return fit, canonical(self.nominal, q, w, self.sigma / np.sqrt(self.samples),
                              start=fit.model, length_mm=PRIOR["length_mm"],
                              angle_deg=PRIOR["angle_deg"])

    def raw(self, model: Any, val: np.ndarray) -> np.ndarray:
        return position_errors(self.true, model, self.q[val], self.tcp)

    def absorbed(self, model: Any, val: np.ndarray) -> np.ndarray:
        return absorbed_errors(self.true, model, self.q[val], self.tcp)

    def design_quality(self, sel: np.ndarray) -> dict[str, Any]:
        Js, _ = scale_columns(self.blocks[sel].reshape(-1, self.blocks.shape[2]))
        sign, ld = np.linalg.slogdet(information(self.blocks, sel))
        return {"observability": observability(Js, len(sel)),
                "log_det": float(ld) if sign > 0 else float("-inf")}


def _setup(arm: str | Any, errors: str, pool: int, seed: int, force_n: float,
           torque_nm: float, samples: int, tcp_mm: Any,
           progress: Progress) -> tuple[_Study, Any, list[str]]:
    nominal = STUDY_ARMS[arm] if isinstance(arm, str) else arm
    rng = np.random.default_rng(seed)
    progress("pool")
    if hasattr(nominal, "candidate_pool"):           # a mechanism with its own workspace
        q = nominal.candidate_pool(pool, rng)
    else:
        q = candidate_pool(nominal.joint_limits_rad, pool, rng)
    sigma = np.array([force_n / 3] * 3 + [torque_nm / 3] * 3)
    names = nominal.parameter_names()
    Jw = jacobian(nominal, q) / np.tile(sigma, pool)[:, None]
    progress("identifiability")
    ident = identifiable(Jw, names)
    blocks = Jw[:, ident.kept_index].reshape(pool, 6, -1)
    in_error = errors_on(nominal, ident, errors)
    true = perturb(nominal, rng, names=in_error, length_mm=PAPER["length_mm"],
                   angle_deg=PAPER["angle_deg"])
    study = _Study(nominal=nominal, true=true, q=q, blocks=blocks, keep=list(ident.kept),
                   sigma=sigma, rng=rng, samples=samples,
                   tcp=np.asarray(tcp_mm, dtype=float))
    return study, ident, in_error


def stages(compare: bool = True) -> list[str]:
    """The stage names :func:`simulate` reports to ``progress``, in order."""
    out = ["pool", "identifiability"]
    for how in SELECTIONS if compare else ("detmax",):
        out += [f"select {how}", f"identify {how}"]
    return out


def _select(study: _Study, how: str, k: int, seed: int) -> np.ndarray:
    if how == "detmax":
        return detmax(study.blocks, k)
    if how == "random":
        return np.random.default_rng([seed, 1]).choice(len(study.q), k, replace=False)
    return _select_by_index(study.blocks, k, how, rng=[seed, 2])


def simulate(arm: str | Any = "ur5e", errors: str = "all", pool: int = 3000,
             k: int = 100, seed: int = 0, force_n: float = PAPER["force_n"],
             torque_nm: float = PAPER["torque_nm"], samples: int = 100,
             compare: bool = True, trials: int = 3, tcp_mm: Any = (0.0, 0.0, 0.0),
             progress: Progress | None = None) -> SimulationResult:
    """Run the simulation study (module docstring) and return its :class:`SimulationResult`.

    ``arm``: a name of ``STUDY_ARMS`` (a registered serial arm, or "medrue") or a model;
    ``errors``: "all", "seen" or "paper" (``ERRORS``); ``pool``: candidate configurations;
    ``k``: the design size; ``force_n`` / ``torque_nm``: the noise bounds (N, N·m);
    ``samples``: readings averaged per configuration (the paper: 100); ``compare``: also run
    the index comparison (else ``indices`` holds DETMAX only); ``trials``: noise draws per
    design (the errors after are pooled over them); ``tcp_mm``: the TCP in the flange frame
    (mm; MedRUE's flange is its probe frame); ``progress(stage)`` is called as each stage
    starts (:func:`stages` lists them). Deterministic for a given ``seed``. Raises ValueError
    on bad settings."""
    if errors not in ERRORS:
        raise ValueError(f"errors must be one of {', '.join(ERRORS)}, not {errors!r}")
    if isinstance(arm, str) and arm not in STUDY_ARMS:
        raise ValueError(f"unknown arm {arm!r}; expected one of {sorted(STUDY_ARMS)}")
    if not 1 <= k < pool:
        raise ValueError(f"k = {k} configurations must be at least 1 and fewer than the pool "
                         f"({pool}), which also supplies the validation configurations")
    if samples < 1 or trials < 1 or force_n <= 0 or torque_nm <= 0:
        raise ValueError("samples and trials must be ≥ 1 and the noise bounds > 0")
    progress = progress or _quiet
    study, ident, in_error = _setup(arm, errors, pool, seed, force_n, torque_nm, samples,
                                    tcp_mm, progress)
    if k * 6 < len(study.keep):
        raise ValueError(f"k = {k} configurations give {6 * k} equations for "
                         f"{len(study.keep)} identifiable parameters; choose more")
    indices: dict[str, dict[str, Any]] = {}
    first_fit: Any = None
    val = np.arange(pool)
    for how in SELECTIONS if compare else ("detmax",):
        progress(f"select {how}")
        sel = _select(study, how, k, seed)
        val_how = np.setdiff1d(np.arange(pool), sel)
        progress(f"identify {how}")
        fits = [study.fit(sel) for _ in range(trials)]
        raw = [study.raw(m, val_how) for _, m in fits]
        absorbed = np.concatenate([study.absorbed(m, val_how) for _, m in fits])
        if how == "detmax":
            first_fit, val = fits[0][0], val_how
        indices[how] = {"after": error_stats(np.concatenate(raw)),
                        "after_absorbed": error_stats(absorbed),
                        "after_mean_mm_per_trial": [float(e.mean()) for e in raw],
                        **study.design_quality(sel)}
    name = arm if isinstance(arm, str) else arm.name
    return SimulationResult(
        settings={"arm": name, "errors": errors, "pool": pool, "k": k, "seed": seed,
                  "force_n": force_n, "torque_nm": torque_nm, "samples": samples,
                  "trials": trials, "tcp_mm": list(map(float, study.tcp))},
        identifiable=list(ident.kept), removed=list(ident.removed), in_error=in_error,
        before=error_stats(study.raw(study.nominal, val)),
        after=indices["detmax"]["after"],
        before_absorbed=error_stats(study.absorbed(study.nominal, val)),
        after_absorbed=indices["detmax"]["after_absorbed"], indices=indices,
        fit={"iterations": first_fit.iterations, "converged": first_fit.converged,
             "reduced_chi2": first_fit.reduced_chi2, "parameters": len(first_fit.parameters)})
