"""The simulation study of force-torque self-calibration (Joubair, Zhao, Bigras and Bonev 2016,
section 5) on a serial arm. Pure numerics, no I/O; docs/selfcal.md ("Simulation study").

The protocol, as the paper runs it:

1. a candidate pool of configurations drawn uniformly within the joint limits (the paper:
   40,000 over the workspace);
2. the identification Jacobian of the nominal model over the pool, rows divided by the
   channel noise; the identifiable parameters (zero columns out, then one dependent column
   at a time, :func:`~tmscal.calib.selfcal.identify.identifiable`);
3. a "true" arm: the nominal one with uniform errors of ±2 mm on lengths and ±1° on angles —
   ``errors="paper"``: on the identifiable parameters only (the paper's Table 1 keeps the
   others, marked *, nominal); ``errors="all"``: on every DH parameter as well (the honest
   case for a lab: link lengths do not change the gravity wrench, so they stay wrong);
4. 100 configurations chosen by O1 (DETMAX: maximising det(JᵀJ) is maximising O1 at a fixed
   count) from the pool; their wrenches from the true arm plus noise of ±1 N and ±0.2 N·m;
5. identification from the nominal start; validation on the rest of the pool: the TCP
   position error (mm, world frame, the flange origin unless ``tcp_mm``) between the true
   arm and the nominal one (before) and the identified one (after): mean, max, SD;
6. the index comparison (the paper's Table 4): the same with the configurations chosen
   greedily by each of O1…O5, by DETMAX and at random.

With ``errors="all"`` the floor is the TCP error left by a noise-free identification: what
the gravity wrench determines exactly; no wrench calibration goes below it. Beside it, the
error with the true values on the identifiable parameters and the nominal on the rest.

The noise: the paper generates it "normally distributed within ±1 N", 100 measurements per
configuration; here each reading is normal with σ = bound/3 (±1 N is 3σ), drawn again beyond
the bound, the ``samples`` readings of a configuration (default 100) are averaged, and the fit
weights rows by σ (that of one reading: the averaged readings' spread is σ/√samples, so
the reduced χ² is about 1/samples).
Orientation parameters of the mounting (base position and yaw, sensor position) carry no
error in either protocol: they move the whole arm rigidly or not at all, and a hand/eye
calibration's Z absorbs them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .design import INDICES, candidate_pool, detmax, information, observability, scale_columns
from .design import select_by_index as _select_by_index
from .identify import error_stats, identifiable, identify, position_errors
from .model import NOMINAL, ArmModel, jacobian, perturb, wrench

__all__ = ["PAPER", "SimulationResult", "simulate", "wrench_noise", "SELECTIONS", "stages"]

#: the paper's figures (Joubair et al. 2016): parameter errors, wrench noise bounds, design
#: size, pool size, and its result in the target workspace (mean, max before → after, mm)
PAPER = {"length_mm": 2.0, "angle_deg": 1.0, "force_n": 1.0, "torque_nm": 0.2, "k": 100,
         "pool": 40000, "before_mean_mm": 8.9135, "after_mean_mm": 0.2771,
         "before_max_mm": 12.0, "after_max_mm": 0.320, "identifiable": 29, "parameters": 49}

#: the selections of the index comparison, in the order reported
SELECTIONS = ("detmax",) + INDICES + ("random",)

Progress = Callable[[str], None]


@dataclass
class SimulationResult:
    """What :func:`simulate` found. Position errors in mm (TCP, world frame).

    ``identifiable``: the identifiable parameter names; ``removed``: [(name, reason)];
    ``in_error``: the parameters given errors; ``before`` / ``after``: {mean_mm, max_mm,
    sd_mm} over the validation configurations, nominal vs identified (the DETMAX design);
    ``floor``: the same for the best any wrench calibration can do — the noise-free
    identification on the DETMAX design (``errors="all"`` only); ``floor_true_values``: the
    true values on the identifiable parameters and the nominal on the rest (not a floor when
    dependent parameters are in error: the wrench determines θ0_2 + θ0_3 + θ0_4 of parallel
    joints, not each); ``indices``: per selection (``SELECTIONS``) {"after": stats pooled over
    the trials, "after_mean_mm_per_trial", "observability": O1…O5 of its design, "log_det":
    log det(JᵀJ)}; ``fit``: iterations, converged, reduced χ² of the
    DETMAX fit; ``settings``: the inputs."""

    settings: dict[str, Any]
    identifiable: list[str]
    removed: list[tuple[str, str]]
    in_error: list[str]
    before: dict[str, float]
    after: dict[str, float]
    floor: dict[str, float] | None
    floor_true_values: dict[str, float] | None = None
    indices: dict[str, dict[str, Any]] = field(default_factory=dict)
    fit: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types; ``floor`` only with ``errors="all"``."""
        out: dict[str, Any] = {
            "settings": self.settings, "identifiable": self.identifiable,
            "removed": [{"name": n, "reason": r} for n, r in self.removed],
            "in_error": self.in_error, "before": self.before, "after": self.after,
            "indices": self.indices, "fit": self.fit}
        if self.floor is not None:
            out["floor"] = self.floor
            out["floor_true_values"] = self.floor_true_values
        return out


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


@dataclass
class _Study:
    """The shared state of one study: the nominal and true arms, the pool and its Jacobian
    blocks on the identifiable columns."""

    nominal: ArmModel
    true: ArmModel
    q: np.ndarray
    blocks: np.ndarray
    keep: list[str]
    sigma: np.ndarray
    rng: np.random.Generator
    samples: int
    tcp: np.ndarray

    def fit(self, sel: np.ndarray, noise: bool = True) -> Any:
        """Measure the configurations ``sel`` on the true arm (plus noise unless ``noise`` is
        False) and identify."""
        q = self.q[sel]
        w = wrench(self.true, q)
        if noise:
            w = w + wrench_noise(self.rng, len(q), 3 * self.sigma[0], 3 * self.sigma[3],
                                 self.samples)
        return identify(self.nominal, q, w, self.sigma, self.keep)

    def position_errors(self, model: ArmModel, val: np.ndarray) -> np.ndarray:
        return position_errors(self.true, model, self.q[val], self.tcp)

    def errors(self, model: ArmModel, val: np.ndarray) -> dict[str, float]:
        return error_stats(self.position_errors(model, val))

    def design_quality(self, sel: np.ndarray) -> dict[str, Any]:
        Js, _ = scale_columns(self.blocks[sel].reshape(-1, self.blocks.shape[2]))
        sign, ld = np.linalg.slogdet(information(self.blocks, sel))
        return {"observability": observability(Js, len(sel)),
                "log_det": float(ld) if sign > 0 else float("-inf")}


def _setup(arm: str | ArmModel, errors: str, pool: int, k: int, seed: int, force_n: float,
           torque_nm: float, samples: int, tcp_mm: Any,
           progress: Progress) -> tuple[_Study, Any, list[str]]:
    nominal = NOMINAL[arm] if isinstance(arm, str) else arm
    rng = np.random.default_rng(seed)
    progress("pool")
    q = candidate_pool(nominal.joint_limits_rad, pool, rng)
    sigma = np.array([force_n / 3] * 3 + [torque_nm / 3] * 3)
    names = nominal.parameter_names()
    Jw = jacobian(nominal, q) / np.tile(sigma, pool)[:, None]
    progress("identifiability")
    ident = identifiable(Jw, names)
    blocks = Jw[:, ident.kept_index].reshape(pool, 6, -1)
    in_error = list(ident.kept)
    if errors == "all":
        dh = [n for n in names if n.split("_")[0] in ("theta0", "d", "a", "alpha")]
        in_error = [n for n in names if n in set(in_error) | set(dh)]
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


def _floors(study: _Study, ident: Any, sel: np.ndarray,
            val: np.ndarray) -> dict[str, dict[str, float]]:
    """With every DH parameter in error: the noise-free identification (what the gravity wrench
    determines; no calibration does better) and the true values on the identifiable
    parameters with the nominal on the rest."""
    p = study.nominal.vector()
    idx = ident.kept_index
    p[idx] = study.true.vector()[idx]
    return {"floor": study.errors(study.fit(sel, noise=False).model, val),
            "floor_true_values": study.errors(study.nominal.with_vector(p), val)}


def _select(study: _Study, how: str, k: int, seed: int) -> np.ndarray:
    if how == "detmax":
        return detmax(study.blocks, k)
    if how == "random":
        return np.random.default_rng([seed, 1]).choice(len(study.q), k, replace=False)
    return _select_by_index(study.blocks, k, how, rng=[seed, 2])


def simulate(arm: str | ArmModel = "ur5e", errors: str = "paper", pool: int = 3000,
             k: int = 100, seed: int = 0, force_n: float = PAPER["force_n"],
             torque_nm: float = PAPER["torque_nm"], samples: int = 100,
             compare: bool = True, trials: int = 3, tcp_mm: Any = (0.0, 0.0, 0.0),
             progress: Progress | None = None) -> SimulationResult:
    """Run the simulation study (module docstring) and return its :class:`SimulationResult`.

    ``arm``: a nominal model name ("ur5e", "vs060") or an :class:`ArmModel`; ``errors``:
    "paper" or "all"; ``pool``: candidate configurations; ``k``: the design size;
    ``force_n`` / ``torque_nm``: the noise bounds (N, N·m); ``samples``: readings averaged per
    configuration (the paper: 100); ``compare``: also run the index comparison (else
    ``indices`` holds DETMAX only); ``trials``: noise draws per design (the errors after are
    pooled over them); ``tcp_mm``: the TCP in the flange frame (mm); ``progress(stage)`` is
    called as each stage starts (:func:`stages` lists them). Deterministic for a given
    ``seed``. Raises ValueError on bad settings."""
    if errors not in ("paper", "all"):
        raise ValueError(f"errors must be 'paper' or 'all', not {errors!r}")
    if isinstance(arm, str) and arm not in NOMINAL:
        raise ValueError(f"unknown arm {arm!r}; expected one of {sorted(NOMINAL)}")
    if not 1 <= k < pool:
        raise ValueError(f"k = {k} configurations must be at least 1 and fewer than the pool "
                         f"({pool}), which also supplies the validation configurations")
    if samples < 1 or trials < 1 or force_n <= 0 or torque_nm <= 0:
        raise ValueError("samples and trials must be ≥ 1 and the noise bounds > 0")
    progress = progress or _quiet
    study, ident, in_error = _setup(arm, errors, pool, k, seed, force_n, torque_nm, samples,
                                    tcp_mm, progress)
    if k * 6 < len(study.keep):
        raise ValueError(f"k = {k} configurations give {6 * k} equations for "
                         f"{len(study.keep)} identifiable parameters; choose more")
    indices: dict[str, dict[str, Any]] = {}
    designs: dict[str, tuple[Any, np.ndarray, np.ndarray]] = {}
    for how in SELECTIONS if compare else ("detmax",):
        progress(f"select {how}")
        sel = _select(study, how, k, seed)
        val = np.setdiff1d(np.arange(pool), sel)
        progress(f"identify {how}")
        fits = [study.fit(sel) for _ in range(trials)]
        errs = np.concatenate([study.position_errors(f.model, val) for f in fits])
        designs[how] = (fits[0], sel, val)
        indices[how] = {"after": error_stats(errs),
                        "after_mean_mm_per_trial": [float(e.mean()) for e in
                                                    np.split(errs, trials)],
                        **study.design_quality(sel)}
    fit, sel, val = designs["detmax"]
    floors = _floors(study, ident, sel, val) if errors == "all" else {}
    name = arm if isinstance(arm, str) else arm.name
    return SimulationResult(
        settings={"arm": name, "errors": errors, "pool": pool, "k": k, "seed": seed,
                  "force_n": force_n, "torque_nm": torque_nm, "samples": samples,
                  "trials": trials,
                  "tcp_mm": list(map(float, study.tcp))},
        identifiable=list(ident.kept), removed=list(ident.removed), in_error=in_error,
        before=study.errors(study.nominal, val), after=indices["detmax"]["after"],
        floor=floors.get("floor"), floor_true_values=floors.get("floor_true_values"),
        indices=indices,
        fit={"iterations": fit.iterations, "converged": fit.converged,
             "reduced_chi2": fit.reduced_chi2, "parameters": len(fit.parameters)})
