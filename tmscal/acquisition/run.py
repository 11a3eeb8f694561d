"""The acquisition run: move → settle → sample → append, for every pose of the plan.

* The plan is regenerated from (kind, P0, seed, ranges) stored in the session header, so
  ``resume`` continues the same plan and skips the indices already recorded — also after a
  crash (each pose is one fsynced line; a torn last line is cut off).
* Every pose is checked against the safety envelope before the first move.
* A device fault (timeout, corrupt reply, lost connection) is retried a bounded number of
  times with a reconnect; a robot fault (protective or emergency stop) stops at once. Either
  way the run ends with ``AcquisitionStopped`` naming the cause, the session intact and
  resumable.
* ``should_stop()`` is polled between poses (the CLI sets it on Ctrl-C): the pose in flight
  is finished, the robot stopped, and the session left valid.

Poses: base_from_flange (A), tracker_from_marker (B), tracker_from_probe (C); 4×4 mm.
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
from ..drivers.base import ConfigError, DeviceError, Robot, RobotFault, SafetyError, Tracker
from ..errors import SessionError, TmscalError
from ..session import PoseRecord, SessionWriter, make_header
from .devices import envelope_for, make_robot, make_tracker
from .plan import check_plan, make_plan
from .sample import PoseSample, sample_pose

log = logging.getLogger(__name__)

__all__ = ["AcquisitionStopped", "AcquireResult", "acquire", "plan_from_header"]


class AcquisitionStopped(TmscalError):
    """The run stopped before the plan was complete; the session is valid and resumable."""


@dataclass
class AcquireResult:
    """What a run did: the session path, poses recorded / skipped / planned, whether it
    stopped early (Ctrl-C), device faults recovered, and wall time (s)."""

    path: Path
    recorded: int
    skipped: int
    total: int
    stopped: bool
    faults: int
    elapsed_s: float
    new_poses: int


def plan_from_header(header: dict[str, Any], poses: int | None = None
                     ) -> tuple[np.ndarray, dict[str, Any]]:
    """Regenerate a session's plan (n, 4, 4) mm from its header's "plan" entry; ``poses``
    changes its length (pose i is the same whatever the length)."""
    p = header.get("plan")
    if not isinstance(p, dict):
        raise ConfigError("the session header has no 'plan' (was it made by tmscal acquire?); "
                          "it cannot be resumed")
    p = dict(p) if poses is None else dict(p, poses=poses)
    try:
        plan = make_plan(p["kind"], np.asarray(p["p0"], dtype=float), int(p["poses"]),
                         int(p["seed"]), float(p["radius_mm"]), float(p["rotation_deg"]))
    except (KeyError, TypeError, ValueError) as e:
        raise ConfigError(f"the session header's 'plan' is incomplete or invalid ({e})") \
            from None
    return plan, p


class _Devices:
    """The open robot and tracker, with reconnect."""

    def __init__(self, cfg: RigConfig, tracker_port: str | None, robot_host: str | None,
                 robot_port: int | None) -> None:
        self.cfg = cfg
        self.tracker_port = tracker_port
        self.robot_host = robot_host
        self.robot_port = robot_port
        self.robot: Robot | None = None
        self.tracker: Tracker | None = None

    def open(self, envelope: Any = None) -> None:
        self.robot = make_robot(self.cfg, envelope, self.robot_host, self.robot_port)
        self.robot.open()
        self.tracker = make_tracker(self.cfg, self.tracker_port)
        self.tracker.open()

    def close(self, stop_robot: bool = False) -> None:
        if self.robot is not None:
            if stop_robot:
                try:
                    self.robot.stop()
                except Exception:  # best effort on the way out
                    log.warning("stopping the robot failed", exc_info=True)
            try:
                self.robot.close()
            except Exception:
                log.warning("closing the robot failed", exc_info=True)
        if self.tracker is not None:
            try:
                self.tracker.close()
            except Exception:
                log.warning("closing the tracker failed", exc_info=True)


_LETTER = {"marker": "B", "probe": "C"}


def _record(i: int, P: np.ndarray, s: PoseSample, t: float) -> PoseRecord:
    """A session line: samples keyed A/B/C as the format says, spreads per body name."""
    samples = {_LETTER.get(k, k): v for k, v in s.samples.items()}
    return PoseRecord(index=i, A=s.A, B=s.bodies.get("marker"), C=s.bodies.get("probe"),
                      commanded=P, time=t, samples=samples, spread=s.spread,
                      skipped=s.problem)


def acquire(cfg: RigConfig, output: str | Path, *, resume: bool = False,
            poses: int | None = None, samples: int | None = None,
            tracker_port: str | None = None, robot_host: str | None = None,
            robot_port: int | None = None,
            on_pose: Callable[[int, int, PoseRecord], None] | None = None,
            on_start: Callable[[int, int], None] | None = None,
            should_stop: Callable[[], bool] = lambda: False,
            sleep: Callable[[float], None] = time.sleep) -> AcquireResult:
    """Run (or resume) an acquisition into session file ``output``.

    ``poses``/``samples`` override the config. ``on_start(done, total)`` is called once the
    plan is known; ``on_pose(done, total, record)`` after each pose is saved. Raises
    SafetyError (nothing moved), ConfigError, SessionError, or AcquisitionStopped (session
    intact, resumable; the message says how)."""
    out = Path(output)
    if cfg.tracker is None or "marker" not in cfg.tracker.tools:
        raise ConfigError(f"{cfg.path}: key 'tracker.tools': name the marker tool 'marker' "
                          "(and the probe 'probe')")
    n_samples = samples or cfg.sampling.samples
    t_start = time.monotonic()
    dev = _Devices(cfg, tracker_port, robot_host, robot_port)
    writer: SessionWriter | None = None
    faults = 0
    new = 0
    stopped = False
    clean = False
    resume_hint = (f"resume with: tmscal acquire {cfg.path} -o {out} --resume")
    try:
        if resume:
            writer = SessionWriter.resume(out)
            # a run extended by --poses earlier keeps its length unless told otherwise
            last = max((r.index for r in writer.session.poses), default=-1)
            n0 = writer.session.header.get("plan", {}).get("poses", 0)
            plan, pinfo = plan_from_header(writer.session.header,
                                           poses or (last + 1 if last + 1 > n0 else None))
            envelope = envelope_for(cfg, np.asarray(pinfo["p0"], dtype=float))
            check_plan(plan, envelope)
            dev.open(envelope)
        else:
            if out.exists():
                raise SessionError(f"{out}: already exists; use --resume to continue it, or "
                                   "choose another file")
            dev.open(envelope_for(cfg, None))  # speed caps only, until P0 is known
            assert dev.robot is not None
            p0 = (dev.robot.flange_pose() if isinstance(cfg.plan.start, str)
                  else np.asarray(cfg.plan.start, dtype=float))
            pinfo = {"kind": cfg.plan.kind, "poses": poses or cfg.plan.poses,
                     "seed": cfg.plan.seed, "radius_mm": cfg.plan.radius_mm,
                     "rotation_deg": cfg.plan.rotation_deg, "p0": p0.tolist()}
            plan, _ = plan_from_header({"plan": pinfo})
            envelope = envelope_for(cfg, p0)
            check_plan(plan, envelope)
            dev.robot.envelope = envelope
        assert dev.robot is not None and dev.tracker is not None
        here = dev.robot.flange_pose()
        v = envelope.violations(here)
        if v:
            raise SafetyError(f"the robot is at {np.round(here[:3, 3], 1).tolist()} mm, "
                              f"outside the safety envelope around P0 ({'; '.join(v)}); "
                              "move it near P0 first. Nothing was moved.")
        if writer is None:
            header = make_header(
                dev.tracker.tools, config=cfg.raw,
                devices={"robot": dev.robot.identity(), "tracker": dev.tracker.identity()},
                plan=pinfo,
                sampling={"samples": n_samples, "settle_s": cfg.sampling.settle_s,
                          "min_share": cfg.sampling.min_share,
                          "robot_reads": cfg.sampling.robot_reads})
            writer = SessionWriter.create(out, header)
        done = writer.session.indices()
        t_offset = max((p.time for p in writer.session.poses), default=0.0)
        total = len(plan)
        if on_start:
            on_start(len(done & set(range(total))), total)
        for i in range(total):
            if i in done:
                continue
            if should_stop():
                stopped = True
                break
            while True:
                try:
                    rec = _one_pose(dev, cfg, i, plan[i], n_samples, sleep,
                                    t_offset + time.monotonic() - t_start)
                    break
                except RobotFault as e:
                    raise AcquisitionStopped(
                        f"pose {i}: robot fault: {e}. The session {out} holds "
                        f"{len(writer.session.poses)} poses; clear the fault at the robot, "
                        f"then {resume_hint}") from e
                except DeviceError as e:
                    faults += 1
                    if faults > cfg.run.retries:
                        raise AcquisitionStopped(
                            f"pose {i}: {e} (after {cfg.run.retries} reconnects). The "
                            f"session {out} holds {len(writer.session.poses)} poses; "
                            f"{resume_hint}") from e
                    log.warning("pose %d: %s; reconnecting (%d of %d)", i, e, faults,
                                cfg.run.retries)
                    dev.close(stop_robot=True)
                    sleep(cfg.run.reconnect_wait_s)
                    try:
                        dev.open(envelope)
                    except DeviceError as e2:
                        raise AcquisitionStopped(
                            f"pose {i}: reconnect failed ({e2}) after: {e}. The session "
                            f"{out} holds {len(writer.session.poses)} poses; {resume_hint}") \
                            from e2
            writer.append(rec)
            new += 1
            if on_pose:
                on_pose(len(writer.session.indices() & set(range(total))), total, rec)
        clean = True
        recs = [p for p in writer.session.poses if p.index < total]
        return AcquireResult(path=out, recorded=sum(p.skipped is None for p in recs),
                             skipped=sum(p.skipped is not None for p in recs), total=total,
                             stopped=stopped, faults=faults,
                             elapsed_s=time.monotonic() - t_start, new_poses=new)
    finally:
        dev.close(stop_robot=not clean)
        if writer is not None:
            writer.close()


def _one_pose(dev: _Devices, cfg: RigConfig, i: int, P: np.ndarray, n_samples: int,
              sleep: Callable[[float], None], t: float) -> PoseRecord:
    """Move to plan pose i, settle and sample; a pose whose bodies were not seen well enough
    is sampled once more (moving again), then recorded as skipped with the reason."""
    assert dev.robot is not None and dev.tracker is not None
    s: PoseSample | None = None
    for attempt in range(2):
        dev.robot.move_to(P)
        s = sample_pose(dev.robot, dev.tracker, n_samples, cfg.sampling.settle_s,
                        cfg.sampling.min_share, cfg.sampling.max_frames_factor, sleep=sleep,
                        robot_reads=cfg.sampling.robot_reads)
        if s.problem is None:
            break
        log.info("pose %d attempt %d: %s", i, attempt + 1, s.problem)
    assert s is not None
    return _record(i, P, s, t)
