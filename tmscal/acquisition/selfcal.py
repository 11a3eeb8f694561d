"""The self-calibration acquisition (``tmscal selfcal acquire``; docs/selfcal.md): move the
robot through selected joint configurations and record, at each, the joint angles and the
averaged force-torque reading of the wrist sensor.

The plan, before anything moves:

* candidates: ``pool`` joint configurations drawn uniformly around the joints the arm has
  now (the wrist within ±``span_deg``, the other joints within a third of it), clipped to
  the nominal model's joint limits (an arm's whole joint range would put nearly every
  candidate outside the workspace box);
* each candidate's flange pose on the NOMINAL model, base_from_flange = base⁻¹ · forward(q)
  (what the controller will be asked to reach), is checked against the config's safety
  envelope around P0 (offset, rotation, the box for the flange and the tool points); the ones
  inside are kept;
* ``k`` of them are chosen for the nominal identification Jacobian, rows weighted by the
  channel noise ``DESIGN_SIGMA``, columns scaled, over the parameters the gravity wrench
  identifies at all: the sequential D-optimal design, then DETMAX exchanges (Mitchell 1974;
  at most ``EXCURSIONS``, never worse than the start). At a fixed k, a larger det(JᵀJ) is a
  larger observability index O1, the index Joubair et al. (2016) found best;
* the chosen configurations are visited in nearest-neighbour order (joint space) from the
  configuration the arm is in.

Every move is a Cartesian flange pose through ``Robot.move_to``, so the envelope is checked
again before each move exactly as in ``tmscal acquire``. At each configuration: wait
``settle_s``, read the joints back (``Robot.joint_positions``, rad), average ``samples``
force-torque readings (N, N·m, sensor frame; mean and SD per channel), read the flange pose,
append one fsynced line (``joints_rad``, ``wrench``, ``wrench_spread``, A, commanded).

The run is a strategy of the one engine (:mod:`tmscal.acquisition.engine`), so crash safety
is the plan run's: the header records the whole plan (configurations and poses) and how it was
drawn (the joints ``q0`` it started from, P0, seed, pool, span), so ``resume`` continues it and
skips the configurations already recorded, after the engine's checks of every resume (the
drivers, the plan, the records, the envelope, where the arm is and how it is turned); Ctrl-C
(``should_stop``) finishes the configuration in flight; a device fault is retried with a
reconnect (``run.retries``); a robot fault stops at once. Either way the session stays valid.

What a resume re-derives (``rederive_poses``): the candidates are a deterministic function of
(q0, seed, pool, span, the arm's joint limits), so they are drawn again and every header
configuration must be one of them, distinct, in the nearest-neighbour order from q0; their
poses are the nominal forward kinematics of their joints, so they are computed again and the
header's must equal them; the engine checks them against the config's envelope. The DETMAX
selection among the candidates is not run again: it is an optimisation in floating point
whose ties may fall differently on another numpy or BLAS, and which candidates it kept does
not bear on safety (every candidate inside the envelope is a safe one). A header from before
``q0_rad`` was recorded gets every check but the draw (noted).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..config import RigConfig
from ..drivers.base import ConfigError, Envelope, SafetyError
from ..errors import CalibrationError, SessionError
from ..geometry import check_pose, invert
from ..session import PoseRecord, Session
from .devices import Devices, Endpoints
from .engine import AcquireResult, Engine
from .plan import check_plan
from .progress import Progress
from .resume import RESUME_HINT, resume_command
from .sample import sample_wrench
from .strategy import Step, Strategy

log = logging.getLogger(__name__)

__all__ = ["DESIGN_SIGMA", "SelfcalPlan", "candidate_configurations", "nominal_poses",
           "select_configurations", "plan_selfcal", "acquire_selfcal", "resume_command",
           "nominal_arm", "SelfcalStrategy", "SelfcalSettings", "measure_wrench",
           "rederive_poses"]

#: channel noise (N, N, N, N·m, N·m, N·m) that weights the design's rows: the wrench noise of
#: Joubair et al.'s (2016) simulation; only the ratio of forces to torques matters here
DESIGN_SIGMA = np.array([1.0, 1.0, 1.0, 0.2, 0.2, 0.2])
#: at most this many configurations in a plan, candidates in a pool
MAX_CONFIGURATIONS = 10_000
MAX_POOL = 100_000
#: DETMAX excursions after the sequential design (each costs a pass over the candidates)
EXCURSIONS = 200


@dataclass(frozen=True)
class SelfcalPlan:
    """A self-calibration plan: the ``arm`` (nominal model's name), the configurations ``q``
    (k, n) rad in visiting order, their nominal flange poses ``poses`` (k, 4, 4)
    base_from_flange mm, ``p0`` (the flange when the plan was made; the envelope's centre),
    and how they were chosen: ``seed``, ``pool`` candidates, ``inside`` of them in the
    envelope, ``span_deg``, ``identifiable`` (the parameters the design was made for),
    the design's O1 and ``q0`` (n,) rad, the joints the candidates were drawn around (None
    in a session recorded before it was kept)."""

    arm: str
    q: np.ndarray
    poses: np.ndarray
    p0: np.ndarray
    seed: int
    pool: int
    inside: int
    span_deg: float
    identifiable: tuple[str, ...] = ()
    o1: float = float("nan")
    q0: np.ndarray | None = None
    arm_definition: dict[str, Any] | None = None

    def to_header(self) -> dict[str, Any]:
        """The session header's "selfcal" entry (plain types)."""
        out = {"arm": self.arm, "configurations": len(self.q), "seed": self.seed,
               "pool": self.pool, "inside": self.inside, "span_deg": self.span_deg,
               "selection": "detmax", "identifiable": list(self.identifiable),
               "o1": None if not np.isfinite(self.o1) else float(self.o1),
               "p0": self.p0.tolist()}
        if self.q0 is not None:
            out["q0_rad"] = self.q0.tolist()
        if self.arm_definition is not None:
            out["arm_definition"] = dict(self.arm_definition)
        return {**out, "q_rad": self.q.tolist(), "poses": self.poses.tolist()}

    @classmethod
    def from_header(cls, header: Any, where: Any = "session") -> SelfcalPlan:
        """The plan a session header records; SessionError if it is missing or invalid (not
        a session of ``tmscal selfcal acquire``, or an edited header)."""
        h = header.get("selfcal") if isinstance(header, dict) else None
        if not isinstance(h, dict):
            raise SessionError(f"{where}: the header has no 'selfcal' plan (was it made by "
                               "tmscal selfcal acquire?); it cannot be resumed")
        try:
            q = np.array(h["q_rad"], dtype=float)
            poses = np.array(h["poses"], dtype=float)
            if q.ndim != 2 or not 1 <= len(q) <= MAX_CONFIGURATIONS or len(poses) != len(q):
                raise ValueError(f"{q.shape[0] if q.ndim else 0} configurations, "
                                 f"{len(poses)} poses")
            if not np.isfinite(q).all():
                raise ValueError("a joint angle is not finite")
            for i, P in enumerate(poses):
                check_pose(P, f"pose {i}")
            seed, pool = _count(h["seed"], "seed"), _count(h["pool"], "pool")
            span = float(h["span_deg"])
            if not (len(q) <= pool <= MAX_POOL and 0 < span <= 180):
                raise ValueError(f"need configurations ≤ pool ≤ {MAX_POOL} and 0 < span_deg "
                                 f"≤ 180, got pool {pool}, span_deg {span}")
            q0 = None
            if h.get("q0_rad") is not None:
                q0 = np.array(h["q0_rad"], dtype=float)
                if q0.shape != q.shape[1:] or not np.isfinite(q0).all():
                    raise ValueError(f"q0_rad: expected {q.shape[1]} finite joint angles")
            o1 = h.get("o1")
            rec = h.get("arm_definition")
            if rec is not None and not isinstance(rec, dict):
                raise ValueError("arm_definition: expected the arm's definition (a mapping)")
            return cls(str(h["arm"]), q, poses, check_pose(h["p0"], "p0"), seed, pool,
                       int(h["inside"]), span, tuple(str(n) for n in h.get("identifiable", [])),
                       float("nan") if o1 is None else float(o1), q0, rec)
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            raise SessionError(f"{where}: the header's 'selfcal' plan is incomplete or "
                               f"invalid ({e})") from None


def _count(v: Any, what: str) -> int:
    """A header's integer ≥ 0 (not a bool, not a float)."""
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise ValueError(f"{what}: expected an integer ≥ 0, got {v!r}")
    return v


# --- the plan (numerics on the nominal model; nothing moves) ----------------------------------

def candidate_configurations(q0: np.ndarray, limits_rad: np.ndarray, n: int, span_deg: float,
                             rng: np.random.Generator) -> np.ndarray:
    """``n`` joint configurations (n, dof) rad drawn uniformly around ``q0`` (rad) and inside
    ``limits_rad`` (dof, 2): the wrist (the last three joints) within ±``span_deg``, the
    joints before it within ±``span_deg``/3. The wrist turns the sensor (what the gravity
    wrench observes) while the flange stays near where it is; the shoulder and elbow carry
    the whole arm, and a third of the span keeps far more of the candidates inside a
    workspace box around P0 than the full span on every joint would."""
    from ..calib.kinematics.excite import joint_window
    from ..calib.selfcal.design import candidate_pool

    q0 = np.asarray(q0, dtype=float)
    lim = np.asarray(limits_rad, dtype=float)
    span = np.full(len(q0), np.radians(span_deg))
    span[:-3] /= 3.0
    lo, hi, j = joint_window(q0, lim, span)
    if j is not None:
        raise SafetyError(f"joint {j + 1} is at {np.degrees(q0[j]):.1f}°, outside the arm's "
                          f"nominal joint limits [{np.degrees(lim[j, 0]):.1f}, "
                          f"{np.degrees(lim[j, 1]):.1f}]°; nothing was moved")
    return candidate_pool(np.stack([lo, hi], axis=1), n, rng)


def nominal_poses(model: Any, q: np.ndarray) -> np.ndarray:
    """The flange poses (m, 4, 4) base_from_flange mm that the controller, whose model is
    ``model``, reaches at joints ``q`` (m, n) rad: base⁻¹ · forward(model, q) (``forward``
    gives world ← flange)."""
    from ..calib.selfcal.model import forward

    return np.einsum("ij,mjk->mik", invert(np.asarray(model.base, dtype=float)),
                     forward(model, np.atleast_2d(q)))


def _design_blocks(model: Any, q: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """The weighted, column-scaled Jacobian blocks (m, 6, L') of the nominal model over the
    parameters the wrench identifies (``identifiable`` on the whole pool), and their names."""
    from ..calib.selfcal.design import scale_columns
    from ..calib.selfcal.identify import identifiable
    from ..calib.selfcal.model import jacobian

    m = len(q)
    J = jacobian(model, q).reshape(m, 6, -1) / DESIGN_SIGMA[None, :, None]
    names = list(model.parameter_names())
    ident = identifiable(J.reshape(6 * m, -1), names)
    keep = [names.index(n) for n in ident.kept]
    Js, _ = scale_columns(J[:, :, keep].reshape(6 * m, -1))
    return Js.reshape(m, 6, -1), [names[i] for i in keep]


def select_configurations(model: Any, q: np.ndarray, k: int, excursions: int = EXCURSIONS
                          ) -> tuple[np.ndarray, list[str], float]:
    """Indices of ``k`` of the configurations ``q`` (m, n) rad chosen for the nominal model's
    identification Jacobian (module docstring): the sequential D-optimal design (each
    configuration added where it raises det(JᵀJ), i.e. O1, most), improved by at most
    ``excursions`` DETMAX excursions (Mitchell 1974; never worse than its start). Returns
    them with the identifiable parameters and the design's O1."""
    from ..calib.selfcal.design import detmax, observability, scale_columns, select_by_index

    blocks, names = _design_blocks(model, q)
    idx = np.asarray(select_by_index(blocks, k, "O1"), dtype=int)
    if excursions > 0:
        idx = np.asarray(detmax(blocks, k, start=idx, max_excursions=excursions), dtype=int)
    o1 = observability(scale_columns(blocks[idx].reshape(6 * len(idx), -1))[0], len(idx))["O1"]
    return idx, names, float(o1)


def _visit_order(q0: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Nearest-neighbour order (largest joint change, rad) through ``q`` from ``q0``."""
    left = list(range(len(q)))
    here, order = np.asarray(q0, dtype=float), []
    while left:
        d = np.abs(q[left] - here).max(axis=1)
        j = left.pop(int(np.argmin(d)))
        order.append(j)
        here = q[j]
    return np.array(order, dtype=int)


def plan_selfcal(model: Any, q0: np.ndarray, p0: np.ndarray, envelope: Envelope, k: int,
                 pool: int, seed: int, span_deg: float) -> SelfcalPlan:
    """The plan (module docstring) for the arm ``model`` (its nominal ArmModel) now at joints
    ``q0`` rad and flange ``p0`` (base_from_flange mm). Raises SafetyError when fewer than
    ``k`` candidates lie inside ``envelope``; every pose of the plan is inside it."""
    if not 1 <= k <= MAX_CONFIGURATIONS or not k <= pool <= MAX_POOL:
        raise ValueError(f"need 1 ≤ k ≤ pool ≤ {MAX_POOL}, got k={k}, pool={pool}")
    rng = np.random.default_rng(seed)
    cand = candidate_configurations(q0, model.joint_limits_rad, pool, span_deg, rng)
    poses = nominal_poses(model, cand)
    inside = np.array([not envelope.violations(P) for P in poses])
    n_in = int(inside.sum())
    if n_in < k:
        raise SafetyError(f"only {n_in} of {pool} candidate configurations (±{span_deg:g}° "
                          f"around the arm's wrist joints) put the flange inside the safety "
                          f"envelope; {k} are needed. Widen safety.max_rotation_deg / "
                          "max_offset_mm or the workspace box, lower --span-deg, or ask for "
                          "fewer configurations (--k). Nothing was moved.")
    cand, poses = cand[inside], poses[inside]
    idx, names, o1 = select_configurations(model, cand, k)
    order = idx[_visit_order(q0, cand[idx])]
    plan = SelfcalPlan(str(model.name), cand[order], poses[order],
                       np.asarray(p0, dtype=float), seed, pool, n_in, float(span_deg),
                       tuple(names), o1, np.asarray(q0, dtype=float).copy())
    check_plan(plan.poses, envelope)
    return plan


#: a header configuration is a candidate of the draw when no joint differs by more (rad)
Q_TOL_RAD = 1e-9


def rederive_poses(plan: SelfcalPlan, model: Any, where: Any = "session"
                   ) -> tuple[np.ndarray, list[str]]:
    """The flange poses (k, 4, 4) base_from_flange mm of a header's plan re-derived from the
    nominal ``model`` (module docstring, "What a resume re-derives"): every configuration
    within the arm's nominal joint limits and, when the header records ``q0``, one of the
    ``pool`` candidates drawn again from (q0, seed, span), distinct, in nearest-neighbour
    order from q0; the poses are the nominal forward kinematics of the header's joints.
    Returns them and the notes (a header without q0). SessionError naming the configuration
    and what differs."""
    q = plan.q
    lim = np.asarray(model.joint_limits_rad, dtype=float)
    edited = f"the header was edited or belongs to another run; {RESUME_HINT}"
    if q.shape[1] != len(lim):
        raise SessionError(f"{where}: the header's configurations have {q.shape[1]} joints; "
                           f"arm {plan.arm!r} has {len(lim)}; {edited}")
    out = (q < lim[:, 0] - Q_TOL_RAD) | (q > lim[:, 1] + Q_TOL_RAD)
    if out.any():
        i, j = np.argwhere(out)[0]
        raise SessionError(f"{where}: configuration {i} of the header puts joint {j + 1} at "
                           f"{np.degrees(q[i, j]):.1f}°, outside arm {plan.arm!r}'s nominal "
                           f"limits; {edited}")
    notes: list[str] = []
    if plan.q0 is None:
        notes.append(f"{where}: the header records no q0_rad (a session from an earlier "
                     "tmscal): its configurations were checked against the arm's limits, its "
                     "forward kinematics and the envelope, not drawn again from the seed")
    else:
        cand = candidate_configurations(plan.q0, lim, plan.pool, plan.span_deg,
                                        np.random.default_rng(plan.seed))
        used: dict[int, int] = {}
        for i, qi in enumerate(q):
            gap = np.abs(cand - qi).max(axis=1)
            c = int(np.argmin(gap))
            if not gap[c] <= Q_TOL_RAD:
                raise SessionError(
                    f"{where}: configuration {i} of the header is none of the {plan.pool} "
                    f"candidates drawn from its seed {plan.seed} around its q0_rad "
                    f"(±{plan.span_deg:g}° at the wrist); {edited}")
            if c in used:
                raise SessionError(f"{where}: configurations {used[c]} and {i} of the header "
                                   f"are the same candidate; {edited}")
            used[c] = i
        if not np.array_equal(_visit_order(plan.q0, q), np.arange(len(q))):
            raise SessionError(f"{where}: the header's configurations are not in the "
                               f"nearest-neighbour order from its q0_rad; {edited}")
    return nominal_poses(model, q), notes


# --- the run ---------------------------------------------------------------------------------

def nominal_arm(arm: Any, where: Any = "--arm") -> Any:
    """The nominal ``ArmModel`` of ``arm``: a registered name (the arm registry,
    ``tmscal.calib.kinematics.ARMS``), a shipped arm file's name, the path of a URDF or arm
    file, or an ``ArmDefinition`` (docs/kinematics.md, "Arm files"); ConfigError naming
    ``where`` and the known names otherwise."""
    from ..solving.selfcal import nominal_model

    return nominal_model(arm, str(where))


def arm_definition_of(arm: str) -> Any:
    """The ``ArmDefinition`` of an ``--arm`` that is not a registered name (None for one)."""
    from ..calib.kinematics import ARMS
    from ..formats.armdef import resolve_arm

    return None if arm in ARMS else resolve_arm(arm, "--arm")


@dataclass(frozen=True)
class SelfcalSettings:
    """What a run does at each configuration: wait ``settle_s``, average ``samples``
    force-torque readings."""

    samples: int
    settle_s: float


def _ft_samples(cfg: RigConfig, header: dict[str, Any] | None, samples: int | None) -> int:
    """--samples, else the resumed session's, else the config's ``ft.samples``."""
    n = ((header or {}).get("sampling") or {}).get("samples") if samples is None else samples
    if isinstance(n, int) and not isinstance(n, bool) and n >= 1:
        return n
    return int(cfg.ft.samples if cfg.ft is not None else 100)


def measure_wrench(dev: Devices, i: int, P: np.ndarray, st: SelfcalSettings, t: float,
                   phase: Callable[[str], None], sleep: Callable[[float], None]
                   ) -> PoseRecord:
    """Move to configuration i's flange pose ``P`` (base_from_flange mm), wait ``settle_s``,
    read the joints (rad), average the force-torque readings (N, N·m; mean and SD per
    channel) and read the flange pose; the record at session time ``t`` (s)."""
    assert dev.robot is not None and dev.ft is not None
    phase("moving")
    dev.robot.move_to(P)
    phase("settling")
    if st.settle_s > 0:
        sleep(st.settle_s)
    phase("sampling")
    q = dev.joints()
    w = sample_wrench(dev.ft, st.samples)
    A = dev.robot.flange_pose()
    return PoseRecord(index=i, A=A, B=None, C=None, commanded=P, time=t,
                      samples={"A": 1, "wrench": w.n}, joints_rad=q.tolist(),
                      wrench=w.mean.tolist(), wrench_spread=w.spread.tolist())


class SelfcalStrategy(Strategy):
    """The self-calibration run: the robot and its force-torque sensor; a new run plans
    ``k`` configurations of the nominal arm ``arm`` from ``pool`` candidates (``seed``,
    ±``span_deg`` at the wrist; :func:`plan_selfcal`) from where the arm is; a resumed run
    reads the plan back from the header. ``samples`` F/T readings per configuration
    (default: the header's on a resume, else ``ft.samples``)."""

    sensor = "ft"
    unit = "configuration"
    command = "selfcal acquire"
    moves_in_order = True   # P0, then the configurations in order, by Cartesian flange moves

    def __init__(self, cfg: RigConfig, arm: str | None = None, k: int = 60, pool: int = 5000,
                 seed: int = 0, span_deg: float = 90.0, samples: int | None = None) -> None:
        super().__init__(cfg)
        self.arm, self.k, self.pool, self.seed, self.span_deg = arm, k, pool, seed, span_deg
        self.samples = samples
        self.model: Any = None
        self.definition: Any = None
        self.st: SelfcalSettings | None = None
        self._notes: list[str] = []

    def check(self) -> None:
        if self.cfg.ft is None:
            raise ConfigError(f"{self.cfg.path}: key 'ft': self-calibration needs a "
                              "force-torque sensor section (ft: {driver, host, ...}; "
                              "docs/configs.md)")

    def prepare(self) -> None:
        if self.arm is None:
            raise ConfigError(f"{self.cfg.path}: name the arm's nominal model (arm=)")
        self.definition = arm_definition_of(self.arm)
        self.model = nominal_arm(self.definition or self.arm)

    def _use(self, plan: SelfcalPlan) -> None:
        self.plan, self.p0, self.poses = plan, plan.p0, plan.poses

    def make_plan(self, dev: Devices, p0: np.ndarray, envelope: Any) -> None:
        plan = plan_selfcal(self.model, dev.joints(), p0, envelope, self.k, self.pool,
                            self.seed, self.span_deg)
        if self.definition is not None:   # a file's arm: the session keeps its definition
            plan = replace(plan, arm_definition=self.definition.record())
        self._use(plan)

    def read(self, session: Session) -> None:
        self._use(SelfcalPlan.from_header(session.header, session.path))

    def rederive(self, session: Session) -> tuple[np.ndarray, str]:
        """The header's configurations drawn again and their poses computed again on the
        nominal model of the header's arm (:func:`rederive_poses`); ``--arm``, when given,
        must name that arm."""
        from ..formats.armdef import arm_from_record

        plan: SelfcalPlan = self.plan
        try:
            recorded = None if plan.arm_definition is None else arm_from_record(
                plan.arm_definition, f"{session.path}: header key 'selfcal.arm_definition'")
            model = nominal_arm(recorded or plan.arm,
                                f"{session.path}: the header's selfcal.arm")
        except (ConfigError, CalibrationError) as e:
            raise SessionError(str(e)) from None
        if self.arm is not None:
            given = arm_definition_of(self.arm)
            same = (given.same_as(recorded) if given is not None and recorded is not None
                    else given is None and recorded is None
                    and nominal_arm(self.arm).name == model.name)
            if not same:
                raise SessionError(f"{session.path}: the session was recorded for arm "
                                   f"{plan.arm!r}; arm={self.arm!r} was given; {RESUME_HINT}")
        poses, self._notes = rederive_poses(plan, model, session.path)
        return poses, (f"arm {plan.arm!r}'s nominal forward kinematics at the header's "
                       "joints")

    def settings(self, header: dict[str, Any] | None) -> list[str]:
        self.st = SelfcalSettings(_ft_samples(self.cfg, header, self.samples),
                                  float(self.cfg.sampling.settle_s))
        return list(self._notes) if header is not None else []

    def header(self) -> dict[str, Any]:
        assert self.st is not None
        return {"selfcal": self.plan.to_header(),
                "sampling": {"samples": self.st.samples, "settle_s": self.st.settle_s}}

    def measure(self, dev: Devices, step: Step, t: float, phase: Callable[[str], None],
                sleep: Callable[[float], None]) -> PoseRecord:
        assert self.st is not None
        return measure_wrench(dev, step.index, step.target, self.st, t, phase, sleep)


def acquire_selfcal(cfg: RigConfig, output: str | Path, *, arm: str | None = None,
                    k: int = 60, pool: int = 5000, seed: int = 0, span_deg: float = 90.0,
                    resume: bool = False, replace: bool = False, samples: int | None = None,
                    robot_host: str | None = None, robot_port: int | None = None,
                    ft_host: str | None = None, ft_port: int | None = None,
                    progress: Progress | None = None,
                    should_stop: Callable[[], bool] = lambda: False,
                    sleep: Callable[[float], None] = time.sleep) -> AcquireResult:
    """Run (or resume) a self-calibration acquisition into session ``output`` (module
    docstring): ``k`` configurations of nominal arm ``arm`` chosen from ``pool`` candidates
    around the arm's joints (±``span_deg`` at the wrist; ``seed`` fixes them); ``samples``
    force-torque readings averaged at each (default: the config's ``ft.samples``); ``ft_host``
    and ``ft_port`` override the sensor's address. On a resume the plan and the sampling come
    from the session header. ``progress`` hears the plan (``planned``, before anything moves)
    and the run, as in :func:`tmscal.acquisition.run.acquire`. Raises SafetyError (nothing
    moved), ConfigError, SessionError, or AcquisitionStopped (session intact, resumable; the
    message says how)."""
    engine = Engine(cfg, output, resume=resume, replace=replace,
                    endpoints=Endpoints(robot_host=robot_host, robot_port=robot_port,
                                        ft_host=ft_host, ft_port=ft_port),
                    should_stop=should_stop, sleep=sleep)
    return engine.run(SelfcalStrategy(cfg, arm, k, pool, seed, span_deg, samples), progress)
