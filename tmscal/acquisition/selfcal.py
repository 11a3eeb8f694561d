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

Crash safety as in :mod:`tmscal.acquisition.run`: the header records the whole plan
(configurations and poses), so ``resume`` continues it and skips the configurations already
recorded, after checking the robot driver, the plan and where the arm is; Ctrl-C
(``should_stop``) finishes the configuration in flight; a device fault is retried with a
reconnect (``run.retries``); a robot fault stops at once. Either way the session stays valid.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import RigConfig
from ..drivers.base import ConfigError, Envelope, Robot, SafetyError
from ..errors import SessionError
from ..geometry import check_pose, invert
from ..session import PoseRecord, SessionWriter, make_header
from .devices import envelope_for, make_robot
from .plan import check_plan
from .run import (
    AcquireResult,
    _check_robot_where_run_stopped,
    with_reconnect,
)

log = logging.getLogger(__name__)

__all__ = ["DESIGN_SIGMA", "SelfcalPlan", "candidate_configurations", "nominal_poses",
           "select_configurations", "plan_selfcal", "acquire_selfcal", "resume_command",
           "nominal_arm"]

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
    envelope, ``span_deg``, ``identifiable`` (the parameters the design was made for) and
    the design's O1."""

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

    def to_header(self) -> dict[str, Any]:
        """The session header's "selfcal" entry (plain types)."""
        return {"arm": self.arm, "configurations": len(self.q), "seed": self.seed,
                "pool": self.pool, "inside": self.inside, "span_deg": self.span_deg,
                "selection": "detmax", "identifiable": list(self.identifiable),
                "o1": None if not np.isfinite(self.o1) else float(self.o1),
                "p0": self.p0.tolist(), "q_rad": self.q.tolist(),
                "poses": self.poses.tolist()}

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
            o1 = h.get("o1")
            return cls(str(h["arm"]), q, poses, check_pose(h["p0"], "p0"), int(h["seed"]),
                       int(h["pool"]), int(h["inside"]), float(h["span_deg"]),
                       tuple(str(n) for n in h.get("identifiable", [])),
                       float("nan") if o1 is None else float(o1))
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            raise SessionError(f"{where}: the header's 'selfcal' plan is incomplete or "
                               f"invalid ({e})") from None


# --- the plan (numerics on the nominal model; nothing moves) ----------------------------------

def candidate_configurations(q0: np.ndarray, limits_rad: np.ndarray, n: int, span_deg: float,
                             rng: np.random.Generator) -> np.ndarray:
    """``n`` joint configurations (n, dof) rad drawn uniformly around ``q0`` (rad) and inside
    ``limits_rad`` (dof, 2): the wrist (the last three joints) within ±``span_deg``, the
    joints before it within ±``span_deg``/3. The wrist turns the sensor (what the gravity
    wrench observes) while the flange stays near where it is; the shoulder and elbow carry
    the whole arm, and a third of the span keeps about half of the candidates inside a
    workspace box around P0 (measured on the UR5e from the mock's P0, ±90°: 52 % inside a
    ±300 mm / ±120° envelope, against 7 % with ±90° on every joint)."""
    q0 = np.asarray(q0, dtype=float)
    lim = np.asarray(limits_rad, dtype=float)
    span = np.full(len(q0), np.radians(span_deg))
    span[:-3] /= 3.0
    lo = np.maximum(lim[:, 0], q0 - span)
    hi = np.minimum(lim[:, 1], q0 + span)
    if (lo > hi).any():
        j = int(np.argmax(lo > hi))
        raise SafetyError(f"joint {j + 1} is at {np.degrees(q0[j]):.1f}°, outside the arm's "
                          f"nominal joint limits [{np.degrees(lim[j, 0]):.1f}, "
                          f"{np.degrees(lim[j, 1]):.1f}]°; nothing was moved")
    from ..calib.selfcal.design import candidate_pool

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
                       tuple(names), o1)
    check_plan(plan.poses, envelope)
    return plan


# --- the run ----------------------------------------------------------------------------------

class _Devices:
    """The open robot and force-torque sensor, with reconnect."""

    def __init__(self, cfg: RigConfig, robot_host: str | None, robot_port: int | None,
                 ft_host: str | None = None, ft_port: int | None = None) -> None:
        self.cfg, self.robot_host, self.robot_port = cfg, robot_host, robot_port
        self.ft_host, self.ft_port = ft_host, ft_port
        self.robot: Robot | None = None
        self.ft: Any = None

    def open(self, envelope: Envelope) -> None:
        from .devices import make_ft

        self.robot = make_robot(self.cfg, envelope, self.robot_host, self.robot_port)
        self.robot.open()
        ft_host = self.ft_host
        on_robot = self.cfg.ft is not None and self.cfg.ft.host in (None, "robot")
        if ft_host is None and on_robot and self.robot_host:
            ft_host = self.robot_host  # a sensor in the arm follows --robot-host
        self.ft = make_ft(self.cfg, ft_host, self.ft_port)
        self.ft.open()

    def close(self, stop_robot: bool = False) -> None:
        steps = [("closing the force-torque sensor", self.ft and self.ft.close)]
        if self.robot is not None:
            steps += [("stopping the robot", stop_robot and self.robot.stop),
                      ("closing the robot", self.robot.close)]
        for what, step in steps:
            try:
                if step:
                    step()
            except Exception:  # best effort on the way out
                log.warning("%s failed", what, exc_info=True)

    def joints(self) -> np.ndarray:
        assert self.robot is not None
        try:
            return np.asarray(self.robot.joint_positions(), dtype=float)
        except NotImplementedError as e:
            raise ConfigError(f"{self.cfg.path}: key 'robot.driver': {e}; self-calibration "
                              "needs the joint angles") from None


@dataclass(frozen=True)
class _Settings:
    """What a run does at each configuration: wait ``settle_s``, average ``samples``
    force-torque readings."""

    samples: int
    settle_s: float


def nominal_arm(arm: str, where: Any = "--arm") -> Any:
    """The nominal ``ArmModel`` of the registered arm named ``arm`` (the arm registry,
    ``tmscal.calib.kinematics.ARMS``); ConfigError naming ``where`` and the known names
    otherwise."""
    from ..calib.kinematics import spec_by_name
    from ..calib.selfcal.model import NOMINAL

    return NOMINAL[spec_by_name(arm, str(where)).name]


def _ft_samples(cfg: RigConfig, header: dict[str, Any] | None, samples: int | None) -> int:
    """--samples, else the resumed session's, else the config's ``ft.samples``."""
    n = ((header or {}).get("sampling") or {}).get("samples") if samples is None else samples
    ok = isinstance(n, int) and not isinstance(n, bool) and n >= 1
    return int(n) if ok else int(cfg.ft.samples if cfg.ft is not None else 100)


def _check_resume(cfg: RigConfig, session: Any, plan: SelfcalPlan) -> None:
    """A resumed session must come from the same robot driver, and its recorded commanded
    poses must be the header plan's (an edited or foreign header would not)."""
    where = session.path
    rec = (session.header.get("devices") or {}).get("robot")
    driver = rec.get("driver") if isinstance(rec, dict) else None
    if cfg.robot is not None and driver != cfg.robot.driver:
        raise SessionError(f"{where}: the session was recorded with robot driver {driver!r}; "
                           f"{cfg.path} configures {cfg.robot.driver!r}; resume with the "
                           "config the session was recorded with")
    for r in session.poses:
        if r.commanded is None or r.index >= len(plan.poses):
            continue
        if not float(np.abs(r.commanded - plan.poses[r.index]).max()) <= 1e-6:
            raise SessionError(f"{where}: configuration {r.index} was commanded elsewhere "
                               "than the header's plan: the header was edited or belongs to "
                               "another run; refusing to resume")


def _start(cfg: RigConfig, out: Path, dev: _Devices, resume: bool, arm: str | None, k: int,
           pool: int, seed: int, span_deg: float, samples: int | None
           ) -> tuple[SessionWriter, SelfcalPlan, Envelope, _Settings]:
    """Open the devices and make (or, resuming, read back and check) the plan; every pose of
    it is checked against the envelope before anything moves; a new session is created."""
    settle = float(cfg.sampling.settle_s)
    if resume:
        writer = SessionWriter.resume(out)
        try:
            plan = SelfcalPlan.from_header(writer.session.header, out)
            _check_resume(cfg, writer.session, plan)
            envelope = envelope_for(cfg, plan.p0)
            check_plan(plan.poses, envelope)
            dev.open(envelope)
            assert dev.robot is not None
            _check_robot_where_run_stopped(dev.robot.flange_pose(), plan.poses, plan.p0,
                                           writer.session.indices(), out)
        except BaseException:
            writer.close()
            raise
        return writer, plan, envelope, _Settings(
            _ft_samples(cfg, writer.session.header, samples), settle)
    if out.exists():
        raise SessionError(f"{out}: already exists; use --resume to continue it, or choose "
                           "another file")
    if arm is None:
        raise ConfigError(f"{cfg.path}: name the arm's nominal model (--arm)")
    model = nominal_arm(arm)
    dev.open(envelope_for(cfg, None))  # the caps and the box until P0 is known
    assert dev.robot is not None
    p0 = dev.robot.flange_pose()
    envelope = envelope_for(cfg, p0)
    plan = plan_selfcal(model, dev.joints(), p0, envelope, k, pool, seed, span_deg)
    dev.robot.envelope = envelope
    st = _Settings(_ft_samples(cfg, None, samples), settle)
    header = make_header(
        ["ft"], config=cfg.raw,
        devices={"robot": dev.robot.identity(), "ft": dev.ft.identity()},
        selfcal=plan.to_header(), sampling={"samples": st.samples, "settle_s": st.settle_s})
    return SessionWriter.create(out, header), plan, envelope, st


def _one(dev: _Devices, i: int, P: np.ndarray, st: _Settings, t: float,
         sleep: Callable[[float], None],
         on_phase: Callable[[int, str], None] | None) -> PoseRecord:
    """Move to configuration i's flange pose, settle, read the joints and the wrench."""
    assert dev.robot is not None and dev.ft is not None
    if on_phase:
        on_phase(i, "moving")
    dev.robot.move_to(P)
    if on_phase:
        on_phase(i, "settling")
    if st.settle_s > 0:
        sleep(st.settle_s)
    if on_phase:
        on_phase(i, "sampling")
    q = dev.joints()
    w = np.asarray(dev.ft.read(st.samples), dtype=float)
    A = dev.robot.flange_pose()
    spread = w.std(axis=0, ddof=1) if len(w) > 1 else np.zeros(6)
    return PoseRecord(index=i, A=A, B=None, C=None, commanded=P, time=t,
                      samples={"A": 1, "wrench": len(w)}, joints_rad=q.tolist(),
                      wrench=w.mean(axis=0).tolist(), wrench_spread=spread.tolist())


def _with_reconnect(dev: _Devices, cfg: RigConfig, envelope: Envelope, i: int,
                    P: np.ndarray, st: _Settings, t: float, sleep: Callable[[float], None],
                    on_phase: Callable[[int, str], None] | None, state: Callable[[], str]
                    ) -> tuple[PoseRecord, int]:
    """One configuration through the acquisition loop's reconnect rule (``run.with_reconnect``:
    at most ``run.retries`` reconnects for it; a robot fault stops)."""
    return with_reconnect(dev, cfg, envelope, "configuration", i,
                          lambda: _one(dev, i, P, st, t, sleep, on_phase), sleep, state,
                          on_phase)


def resume_command(config: str | Path | None, out: str | Path, robot_host: str | None = None,
                   ft_host: str | None = None) -> str:
    """The command that resumes a self-calibration run (the plan is in the session; device
    overrides are repeated, ``ft_host`` as HOST[:PORT])."""
    cmd = f"tmscal selfcal acquire {config} -o {out} --resume"
    cmd += f" --robot-host {robot_host}" if robot_host else ""
    return cmd + (f" --ft-host {ft_host}" if ft_host else "")


def acquire_selfcal(cfg: RigConfig, output: str | Path, *, arm: str | None = None,
                    k: int = 60, pool: int = 5000, seed: int = 0, span_deg: float = 90.0,
                    resume: bool = False, samples: int | None = None,
                    robot_host: str | None = None, robot_port: int | None = None,
                    ft_host: str | None = None, ft_port: int | None = None,
                    on_plan: Callable[[SelfcalPlan], None] | None = None,
                    on_start: Callable[[int, int, int], None] | None = None,
                    on_pose: Callable[[int, int, PoseRecord], None] | None = None,
                    on_phase: Callable[[int, str], None] | None = None,
                    should_stop: Callable[[], bool] = lambda: False,
                    sleep: Callable[[float], None] = time.sleep) -> AcquireResult:
    """Run (or resume) a self-calibration acquisition into session ``output`` (module
    docstring): ``k`` configurations of nominal arm ``arm`` chosen from ``pool`` candidates
    around the arm's joints (±``span_deg`` at the wrist; ``seed`` fixes them); ``samples``
    force-torque readings averaged at each (default: the config's ``ft.samples``); ``ft_host``
    and ``ft_port`` override the sensor's address. On a resume the plan and the sampling come
    from the session header. ``on_plan(plan)`` hears the plan before anything moves; the
    other callbacks are those of :func:`tmscal.acquisition.run.acquire`. Raises SafetyError
    (nothing moved), ConfigError, SessionError, or AcquisitionStopped (session intact,
    resumable; the message says how)."""
    out = Path(output)
    if cfg.ft is None:
        raise ConfigError(f"{cfg.path}: key 'ft': self-calibration needs a force-torque "
                          "sensor section (ft: {driver, host, ...}; docs/configs.md)")
    t_start = time.monotonic()
    dev = _Devices(cfg, robot_host, robot_port, ft_host, ft_port)
    writer: SessionWriter | None = None
    new = faults = 0
    stopped = clean = False
    ft = None if ft_host is None else ft_host + (f":{ft_port}" if ft_port else "")
    hint = "resume with: " + resume_command(cfg.path, out, robot_host, ft)
    try:
        writer, plan, envelope, st = _start(cfg, out, dev, resume, arm, k, pool, seed,
                                            span_deg, samples)
        if on_plan:
            on_plan(plan)
        done = writer.session.indices()
        total = len(plan.poses)
        t_offset = max((p.time for p in writer.session.poses), default=0.0)
        if on_start:
            on_start(len(done), total, 0)
        for i in range(total):
            if i in done:
                continue
            if should_stop():
                stopped = True
                break
            rec, n = _with_reconnect(
                dev, cfg, envelope, i, plan.poses[i], st,
                t_offset + time.monotonic() - t_start, sleep, on_phase,
                lambda: f"The session {out} holds {len(writer.session.poses)} "
                        f"configurations; {hint}")
            faults += n
            writer.append(rec)
            new += 1
            if on_pose:
                on_pose(len(writer.session.indices()), total, rec)
        clean = True
        n_rec = len(writer.session.indices() & set(range(total)))
        return AcquireResult(path=out, recorded=n_rec, skipped=0, total=total,
                             stopped=stopped, faults=faults,
                             elapsed_s=time.monotonic() - t_start, new_poses=new)
    finally:
        dev.close(stop_robot=not clean)
        if writer is not None:
            writer.close()
