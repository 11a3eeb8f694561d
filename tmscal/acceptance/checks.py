"""The rig acceptance checks (``docs/acceptance.md``): the driver contract of
``tmscal.drivers.base`` exercised on the devices a rig config names, real or mock.

Each check returns a :class:`Check` (pass, fail or skip, the measured values, a note) instead
of raising, so that one run can report every check: ``tmscal selftest --rig CONFIG`` prints
them and ``pytest tests/acceptance --rig CONFIG`` asserts on them, both through
:class:`tmscal.acceptance.rig.RigSelftest` (the devices, the order, the skips), and
both write the same text report (:func:`format_report`).

Frames and units as everywhere (``docs/conventions.md``): poses base_from_flange 4×4 mm,
distances mm, angles degrees at this edge, rates Hz, times s. Every move goes through
``Robot.move_to`` with the config's envelope around the flange pose at the start of the check
(``envelope_for(cfg, p0)``, ``docs/safety.md``): a step that would leave it is never sent.
"""

from __future__ import annotations

import datetime as _dt
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..acquisition.devices import envelope_for
from ..config import RigConfig
from ..errors import TmscalError
from ..escape import value_text
from ..geometry import angle_between, check_pose

__all__ = ["Check", "Settings", "CHECK_NAMES", "check_connect", "check_tools",
           "check_small_move", "check_stop", "check_reconnect", "format_report",
           "result_text", "stable_identity"]

#: the checks in the order they run, with the line the report gives each
CHECK_NAMES = {
    "connect": "connect and identity",
    "tools": "tool visibility and frame rate",
    "move": "small move inside the envelope and back",
    "stop": "stop while moving",
    "reconnect": "close, open again, identity unchanged",
}

#: identity keys that a device assigns per connection (NDI port handles come from PHRQ on
#: every initialisation, NDI Combined API): not compared by the reconnect check
PER_CONNECTION_KEYS = ("handles",)

#: base-frame directions tried, in order, for a step (up first: away from a table or a head)
DIRECTIONS = (("+z", (0, 0, 1)), ("+x", (1, 0, 0)), ("-x", (-1, 0, 0)), ("+y", (0, 1, 0)),
              ("-y", (0, -1, 0)), ("-z", (0, 0, -1)))


@dataclass(frozen=True)
class Settings:
    """What the checks measure and their tolerances.

    ``frames``: distinct tracker frames read by the tools check; ``rate_tolerance``: the
    largest relative difference between the measured frame rate and ``frame_rate_hz``
    (asserted on a real-time device only); ``step_mm``: the small move; ``pos_tol_mm`` /
    ``rot_tol_deg``: how close the reported flange must arrive; ``stop_mm`` and
    ``stop_move_s``: the length and the planned duration of the move that is stopped (its
    speed is ``stop_mm / stop_move_s``, never above ``robot.speed_mm_s``); ``stop_after``:
    the share of ``stop_move_s`` after which ``stop()`` is called; ``real_time``: False on the
    mock's fast clock or an in-process sim device (no frame-rate verdict, no stop check),
    ``clock`` naming which in the notes and ``clock_hint`` what to use instead ("": none)."""

    frames: int = 100
    rate_tolerance: float = 0.10
    step_mm: float = 10.0
    pos_tol_mm: float = 0.5
    rot_tol_deg: float = 0.5
    stop_mm: float = 40.0
    stop_move_s: float = 2.0
    stop_after: float = 0.25
    real_time: bool = True
    clock: str = "the mock's fast clock"
    clock_hint: str = "use mock.clock: real"


@dataclass
class Check:
    """One check's outcome: ``status`` "pass", "fail" or "skip"; ``values`` what was measured
    (plain data, units in the key names); ``note`` why it failed or was skipped."""

    key: str
    status: str
    values: dict[str, Any] = field(default_factory=dict)
    note: str = ""

    @property
    def title(self) -> str:
        return CHECK_NAMES.get(self.key, self.key)

    def summary(self) -> str:
        """One line: the verdict, the check, the note."""
        return f"{self.status.upper():4}  {self.title}" + (f": {self.note}" if self.note else "")


def _guarded(key: str, fn: Callable[[dict[str, Any]], Check]) -> Check:
    """Run one check; a tmscal error (a device fault, a refused move) is its failure, with
    whatever was measured before it."""
    values: dict[str, Any] = {}
    try:
        return fn(values)
    except TmscalError as e:
        return Check(key, "fail", values, f"{type(e).__name__}: {e}")


def stable_identity(identity: dict[str, Any]) -> dict[str, Any]:
    """A device identity without the keys assigned per connection (``PER_CONNECTION_KEYS``)."""
    return {k: v for k, v in identity.items() if k not in PER_CONNECTION_KEYS}


def _pose_values(T: np.ndarray) -> list[float]:
    return [round(float(v), 3) for v in T[:3, 3]]


# --- connect and identity --------------------------------------------------------------------

def check_connect(tracker: Any, robot: Any) -> Check:
    """Open the devices (either may be None), read their identities, one tracker frame with
    every configured tool and the flange pose (a finite rigid 4×4)."""
    def run(v: dict[str, Any]) -> Check:
        for kind, dev in (("tracker", tracker), ("robot", robot)):
            if dev is not None:
                dev.open()
                v[f"{kind}_identity"] = dev.identity()
        if tracker is not None:
            frame = tracker.read()
            absent = [t for t in tracker.tools if t not in frame.tools]
            v["tracker_frame"] = frame.frame
            if absent:
                return Check("connect", "fail", v, f"the tracker frame lacks tools {absent}")
        if robot is not None:
            try:
                pose = check_pose(robot.flange_pose(), "flange pose")
            except ValueError as e:
                return Check("connect", "fail", v, f"flange pose: {e}")
            v["flange_mm"] = _pose_values(pose)
        return Check("connect", "pass", v)
    return _guarded("connect", run)


# --- tools and frame rate --------------------------------------------------------------------

def check_tools(tracker: Any, min_share: float, s: Settings) -> Check:
    """Read ``s.frames`` distinct frames: every configured tool must be usable (present and
    inside the volume) in at least ``min_share`` of them. The frame rate (the device's frame
    counter over host time between the first and the last frame read; the distinct frames
    read when the counter wrapped) is reported against
    ``tracker.frame_rate_hz``, and asserted within ``s.rate_tolerance`` only if
    ``s.real_time``."""
    def run(v: dict[str, Any]) -> Check:
        n = max(2, int(s.frames))
        # a bound against a device that sends nothing, not a rate check: long enough for the
        # slowest rate the tolerance accepts and for a busy host polling slowly (20× nominal)
        slowest = tracker.frame_rate_hz * max(1.0 - s.rate_tolerance, 0.05)
        frames = list(tracker.distinct_frames(
            n, timeout_s=10.0 + max(20.0 * n / tracker.frame_rate_hz, n / slowest)))
        share = {t: sum(f.tools[t].usable for f in frames if t in f.tools) / len(frames)
                 for t in tracker.tools}
        span = frames[-1].host_time - frames[0].host_time
        nums = [f.frame for f in frames]
        # the device's own frame counter over host time: the tracker's rate, whether or not
        # this process read every frame (a busy host polls slower than the device runs)
        ticks = nums[-1] - nums[0] if nums[-1] > nums[0] else len(frames) - 1
        rate = ticks / span if span > 0 else math.inf
        v.update(frames=len(frames), min_share=min_share,
                 usable_share={t: round(x, 3) for t, x in share.items()},
                 frame_rate_hz=round(rate, 2), configured_rate_hz=tracker.frame_rate_hz,
                 frame_numbers=f"{nums[0]}..{nums[-1]}", real_time=s.real_time)
        low = {t: x for t, x in share.items() if x < min_share}
        if low:
            seen = {t: sum(f.tools[t].usable for f in frames if t in f.tools) for t in low}
            return Check("tools", "fail", v, ", ".join(
                f"{t} seen in {k} of {len(frames)} frames" for t, k in seen.items())
                + f", below sampling.min_share {min_share:g}")
        if not s.real_time:
            return Check("tools", "pass", v, f"frame rate reported only ({s.clock})")
        off = abs(rate / tracker.frame_rate_hz - 1.0)
        v["rate_error"] = round(off, 4)
        if not off <= s.rate_tolerance:
            return Check("tools", "fail", v, f"frame rate {rate:.2f} Hz is {off:.1%} off "
                         f"frame_rate_hz {tracker.frame_rate_hz:g} (tolerance "
                         f"{s.rate_tolerance:.0%})")
        return Check("tools", "pass", v)
    return _guarded("tools", run)


# --- moves -----------------------------------------------------------------------------------

def _step_target(robot: Any, cfg: RigConfig, length_mm: float) -> tuple[np.ndarray, np.ndarray,
                                                                         str]:
    """(P0, target, direction): the first base-axis step of ``length_mm`` from the current
    flange pose that the config's envelope around it allows; the robot gets that envelope."""
    p0 = check_pose(robot.flange_pose(), "flange pose")
    env = envelope_for(cfg, p0)
    robot.envelope = env
    tried = []
    for name, d in DIRECTIONS:
        target = p0.copy()
        target[:3, 3] += length_mm * np.asarray(d, dtype=np.float64)
        why = env.violations(target)
        if not why:
            return p0, target, name
        tried.append(f"{name}: {why[0]}")
    from ..errors import SafetyError
    raise SafetyError(f"no {length_mm:g} mm step along a base axis from the flange at "
                      f"{_pose_values(p0)} mm stays inside the envelope ({'; '.join(tried)}); "
                      "nothing was moved")


def _arrival(robot: Any, target: np.ndarray) -> tuple[float, float]:
    """(distance mm, angle deg) of the reported flange from ``target``."""
    here = robot.flange_pose()
    return (float(np.linalg.norm(here[:3, 3] - target[:3, 3])),
            float(np.degrees(angle_between(here, target))))


def check_small_move(robot: Any, cfg: RigConfig, s: Settings) -> Check:
    """Move ``s.step_mm`` along a base axis (the first one the envelope allows) and back, at
    the configured speed; after ``sampling.settle_s`` (the wait acquire makes before it
    samples) the reported flange must be within ``s.pos_tol_mm`` and ``s.rot_tol_deg`` of
    the target each time. The distance as ``move_to`` returns is reported too."""
    settle_s = cfg.sampling.settle_s

    def run(v: dict[str, Any]) -> Check:
        p0, target, axis = _step_target(robot, cfg, s.step_mm)
        v.update(start_mm=_pose_values(p0), axis=axis, step_mm=s.step_mm,
                 speed_mm_s=robot.speed_mm_s, settle_s=settle_s)
        bad = []
        for leg, goal in (("out", target), ("back", p0)):
            robot.move_to(goal)
            v[f"{leg}_on_return_error_mm"] = round(_arrival(robot, goal)[0], 4)
            if settle_s > 0:
                time.sleep(settle_s)  # as acquire waits before it samples
            d, a = _arrival(robot, goal)
            v[f"{leg}_error_mm"], v[f"{leg}_error_deg"] = round(d, 4), round(a, 4)
            if not (d <= s.pos_tol_mm and a <= s.rot_tol_deg):
                bad.append(f"{leg}: flange {d:.3f} mm / {a:.3f}° from the target "
                           f"(tolerance {s.pos_tol_mm:g} mm / {s.rot_tol_deg:g}°)")
        return Check("move", "fail" if bad else "pass", v, "; ".join(bad))
    return _guarded("move", run)


def _stopped_move(robot: Any, target: np.ndarray, speed: float, wait_s: float,
                  guard_s: float, v: dict[str, Any]) -> bool:
    """Start ``move_to(target, speed)`` in a thread, call ``stop()`` after ``wait_s``, wait
    (at most ``guard_s``) for the move to end. Returns whether it ended; the move's own
    outcome (returned, or the error a halted move raises) goes into ``v``."""
    outcome: list[str] = []
    started = threading.Event()

    def move() -> None:
        started.set()
        try:
            robot.move_to(target, speed)
            outcome.append("returned")
        except TmscalError as e:
            outcome.append(f"{type(e).__name__}: {e}")

    t = threading.Thread(target=move, name="acceptance-stop-move", daemon=True)
    t0 = time.monotonic()
    t.start()
    started.wait(guard_s)
    time.sleep(wait_s)  # pacing at the rig, not a measurement: let the arm get going
    t_stop = time.monotonic()
    robot.stop()
    v["stop_called_after_s"] = round(t_stop - t0, 3)
    v["stop_returned_after_s"] = round(time.monotonic() - t_stop, 3)
    t.join(guard_s)
    if t.is_alive():
        return False
    v["move_ended_after_stop_s"] = round(time.monotonic() - t_stop, 3)
    v["move_outcome"] = outcome[0] if outcome else "no outcome"
    return True


def check_stop(robot: Any, cfg: RigConfig, s: Settings) -> Check:
    """Start a ``s.stop_mm`` move planned to take ``s.stop_move_s``, call ``stop()`` after
    ``s.stop_after`` of it: the move must end (a halted move may raise) and the flange must be
    short of the target by more than ``s.pos_tol_mm``; then the flange is moved back to the
    start. Skipped on the mock's fast clock and on an in-process sim robot, where every move
    completes at once."""
    if not s.real_time:
        hint = f" ({s.clock_hint})" if s.clock_hint else ""
        return Check("stop", "skip", {}, f"{s.clock} completes a move at once, so stop() "
                     f"cannot land mid-move{hint}")

    def run(v: dict[str, Any]) -> Check:
        p0, target, axis = _step_target(robot, cfg, s.stop_mm)
        speed = min(robot.speed_mm_s, s.stop_mm / s.stop_move_s)
        v.update(start_mm=_pose_values(p0), axis=axis, length_mm=s.stop_mm,
                 speed_mm_s=round(speed, 3))
        guard = 10.0 + 3.0 * s.stop_mm / speed
        if not _stopped_move(robot, target, speed, s.stop_after * s.stop_move_s, guard, v):
            robot.stop()
            return Check("stop", "fail", v, f"the move did not end within {guard:g} s of "
                         "stop()")
        if cfg.sampling.settle_s > 0:
            time.sleep(cfg.sampling.settle_s)  # the arm decelerates to rest
        here = robot.flange_pose()
        left = float(np.linalg.norm(here[:3, 3] - target[:3, 3]))
        v.update(moved_mm=round(float(np.linalg.norm(here[:3, 3] - p0[:3, 3])), 3),
                 short_of_target_mm=round(left, 3))
        robot.move_to(p0)
        if cfg.sampling.settle_s > 0:
            time.sleep(cfg.sampling.settle_s)
        d, _ = _arrival(robot, p0)
        v["back_error_mm"] = round(d, 4)
        if not left > s.pos_tol_mm:
            return Check("stop", "fail", v, f"the flange reached the target ({left:.3f} mm "
                         "from it): stop() did not halt the move")
        if not d <= s.pos_tol_mm:
            return Check("stop", "fail", v, f"back at the start: flange {d:.3f} mm from it")
        return Check("stop", "pass", v)
    return _guarded("stop", run)


# --- reconnect -------------------------------------------------------------------------------

def check_reconnect(tracker: Any, robot: Any, s: Settings) -> Check:
    """Close both devices, open them again: the identities (less ``PER_CONNECTION_KEYS``) are
    unchanged, the tracker gives a frame and the flange is where it was (within
    ``s.pos_tol_mm``)."""
    def run(v: dict[str, Any]) -> Check:
        devs = [(k, d) for k, d in (("tracker", tracker), ("robot", robot)) if d is not None]
        before = {k: stable_identity(d.identity()) for k, d in devs}
        pose = robot.flange_pose() if robot is not None else None
        for _, d in devs:
            d.close()
        for _, d in devs:
            d.open()
        after = {k: stable_identity(d.identity()) for k, d in devs}
        changed = sorted(f"{k}.{key}" for k in before
                         for key in set(before[k]) | set(after[k])
                         if before[k].get(key) != after[k].get(key))
        v["identity_changed"] = changed
        if tracker is not None:
            v["tracker_frame"] = tracker.read().frame
        if pose is not None:
            d, _ = _arrival(robot, pose)
            v["flange_moved_mm"] = round(d, 4)
            if not d <= s.pos_tol_mm:
                return Check("reconnect", "fail", v, f"the flange reads {d:.3f} mm from where "
                             "it was before the reconnect")
        if changed:
            return Check("reconnect", "fail", v, f"identity changed: {', '.join(changed)}")
        return Check("reconnect", "pass", v)
    return _guarded("reconnect", run)


# --- the report ------------------------------------------------------------------------------

def _value_lines(values: dict[str, Any]) -> list[str]:
    out = []
    for k, val in values.items():
        if isinstance(val, dict) and k.endswith("identity"):
            out.append(f"      {k}:")
            out += [f"        {ik}: {value_text(iv)}" for ik, iv in val.items()]
        else:
            out.append(f"      {k}: {value_text(val)}")
    return out


def result_text(checks: list[Check]) -> str:
    """The verdict of the checks run: "PASS (5 passed, 0 failed, 0 skipped)" or "FAIL (…)"
    (a skip does not fail)."""
    counts = {st: sum(c.status == st for c in checks) for st in ("pass", "fail", "skip")}
    return (f"{'FAIL' if counts['fail'] else 'PASS'} ({counts['pass']} passed, "
            f"{counts['fail']} failed, {counts['skip']} skipped)")


def format_report(config_path: str, checks: list[Check], meta: dict[str, Any] | None = None,
                  when: _dt.datetime | None = None) -> str:
    """The text report a lab keeps: date, config, ``meta`` (how the run was made), then every
    check (of ``CHECK_NAMES``, "not run" for a missing one) with its verdict and values."""
    from .. import __version__

    when = when or _dt.datetime.now().astimezone()
    lines = ["tmscal rig acceptance report", f"date: {when.isoformat(timespec='seconds')}",
             f"config: {config_path}", f"tmscal: {__version__}"]
    lines += [f"{k}: {val}" for k, val in (meta or {}).items()]
    by_key = {c.key: c for c in checks}
    lines += ["", f"result: {result_text(checks)}", ""]
    for key in [*CHECK_NAMES, *(k for k in by_key if k not in CHECK_NAMES)]:
        c = by_key.get(key) or Check(key, "not run", {}, "")
        lines.append(f"[{c.status.upper()}] {c.title}")
        if c.note:
            lines.append(f"      note: {c.note}")
        lines += _value_lines(c.values)
    return "\n".join(lines) + "\n"
