"""Sampling at one pose: settle, collect tracker frames with the robot pose read alongside,
drop frames in which a body is missing or out of volume, average.

Settling (``settle``):

* ``"still"`` (default): read tracker frames until every tracked body has been still over the
  last ``still_window_s`` of frames (the window, counted in distinct frames at the tracker's
  nominal rate, at least ``MIN_WINDOW_FRAMES``; no longer than ``settle_s``), with ``settle_s``
  seconds as the upper bound (one full window is always judged, even if that takes longer).
  Still means: the RMS distance of the body's positions from their mean over the window (its
  spread, mm) is at most the tolerance, ``still_tol_mm`` when given, else
  ``STILL_NOISE_MULTIPLE`` · √3 · σ̂ with a floor of ``STILL_FLOOR_MM``. σ̂ is the tracker's
  per-axis noise estimated from the window itself, robustly, from the second differences of
  successive positions (median of |x[i+1] − 2x[i] + x[i−1]| / (0.6745·√6), pooled over the
  axes). White noise alone gives a spread of about √3·σ, so a still body passes. A motion
  does not inflate σ̂ the way it inflates the spread: second differences see an oscillation of
  frequency f at frame rate R attenuated by (2·sin(πf/R))² (0.17 for 4 Hz at 60 Hz, i.e. about
  3 % of its variance), while the spread over the window sees it whole; that is why a slow
  oscillation or drift is not mistaken for noise. Its limit: a motion whose travel within the
  window is below the tolerance is still by this rule (lengthen ``still_window_s`` for a very
  slow one). The frames read while settling are not averaged in. A body not usable in at
  least 3 frames of the window is not judged (the usable-share check of the sampling names
  it). Not still after ``settle_s`` makes the pose a problem: "not still after X s (marker
  0.140 mm RMS over the last window of 12 frames, tolerance 0.061 mm)".
* ``"fixed"``: wait ``settle_s`` seconds.
* ``settle_s`` 0: no settling at all, in either mode.

Samples: a fixed ``n_samples`` distinct frames (``sem_mm`` None), or by need: stop as soon as
every body's standard error of the mean position, its spread / √k after k usable frames, is at
most ``sem_mm``, with ``min_samples`` as the floor and ``n_samples`` as the cap.

Wrench (a tracker run with a force-torque sensor; a self-calibration run): ``sample_wrench``
averages n consecutive readings [Fx, Fy, Fz N, Tx, Ty, Tz N·m] (sensor frame) and gives their
standard deviation per channel.

Averages: translations by arithmetic mean, rotations by the chordal L2 mean. Spreads: RMS
distance of the samples' origins from the mean (mm) and RMS rotation angle from the mean
rotation (deg). Frames: A = base_from_flange (robot), tracker_from_<body> per tool; 4×4 mm.
Times: seconds on the monotonic clock (``clock``).
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..config import SETTLE_MODES, SamplingConfig
from ..config.run import check_sampling
from ..drivers.base import ForceTorque, Robot, ToolState, Tracker
from ..errors import ConfigError
from ..geometry import angle_between, pose_mean
from ..timing import Deadline

log = logging.getLogger(__name__)

__all__ = ["PoseSample", "sample_pose", "sample_wrench", "WrenchSample", "spread_of",
           "noise_sigma_mm", "stillness", "window_frames", "SETTLE_MODES",
           "STILL_NOISE_MULTIPLE", "STILL_FLOOR_MM", "MIN_WINDOW_FRAMES"]

#: the stillness tolerance, when not given, is this multiple of white noise's spread √3·σ̂
STILL_NOISE_MULTIPLE = 2.0
#: the tolerance from the noise is never below this (mm): a quantised or noise-free tracker
#: (σ̂ = 0) would otherwise never read as still
STILL_FLOOR_MM = 0.02
#: the stillness window holds at least this many distinct frames (a noise estimate from
#: second differences needs a few)
MIN_WINDOW_FRAMES = 6
#: a body needs this many usable frames in the window to be judged
_MIN_JUDGED = 3
#: median |N(0, 1)|: turns a median absolute value into a standard deviation
_MAD = 0.6745


@dataclass
class PoseSample:
    """The result at one pose: averaged A and per-body poses (None when a body had too few
    usable frames), sample counts, spreads, the share of usable frames per body, and the
    reason when the pose is unusable. ``settling_s`` and ``sampling_s`` are the seconds
    (monotonic clock) spent settling and sampling; ``still`` is True when the stillness test
    passed before sampling (False with ``settle="fixed"``, with ``settle_s`` 0, and for a
    pose that never became still). ``joints``: the robot's joint angles (rad), read once
    after sampling, when its driver reports them (else None)."""

    A: np.ndarray
    bodies: dict[str, np.ndarray | None]
    samples: dict[str, int]
    spread: dict[str, dict[str, float]]
    share: dict[str, float]
    frames: int
    first_frame: int
    last_frame: int
    problem: str | None = None
    flags: dict[str, int] = field(default_factory=dict)
    settling_s: float = 0.0
    sampling_s: float = 0.0
    still: bool = False
    joints: np.ndarray | None = None


def read_joints(robot: Robot) -> np.ndarray | None:
    """The robot's joint angles (rad) from ``Robot.joint_positions``, or None when its driver
    does not report them (NotImplementedError)."""
    try:
        return np.asarray(robot.joint_positions(), dtype=np.float64)
    except NotImplementedError:
        return None


@dataclass(frozen=True)
class WrenchSample:
    """The averaged wrench (6,) [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame, its
    sample standard deviation per channel (6,) (zeros for one reading), and the count."""

    mean: np.ndarray
    spread: np.ndarray
    n: int


def sample_wrench(ft: ForceTorque, n: int) -> WrenchSample:
    """Read ``n`` consecutive force-torque readings and average them (the robot holds
    still). DeviceError from the sensor passes on (the engine reconnects)."""
    w = np.asarray(ft.read(n), dtype=np.float64).reshape(-1, 6)
    spread = w.std(axis=0, ddof=1) if len(w) > 1 else np.zeros(6)
    return WrenchSample(w.mean(axis=0), spread, len(w))


def spread_of(poses: np.ndarray, mean: np.ndarray) -> dict[str, float]:
    """RMS translation (mm) and rotation (deg) of poses (k, 4, 4) about their mean."""
    dt = np.linalg.norm(poses[:, :3, 3] - mean[:3, 3], axis=1)
    da = np.degrees(angle_between(mean, poses))
    return {"trans_mm": float(np.sqrt((dt ** 2).mean())),
            "rot_deg": float(np.sqrt((da ** 2).mean()))}


def window_frames(still_window_s: float, frame_rate_hz: float) -> int:
    """Distinct frames in a stillness window of ``still_window_s`` seconds at the tracker's
    nominal ``frame_rate_hz``: at least ``MIN_WINDOW_FRAMES``."""
    return max(MIN_WINDOW_FRAMES, int(math.ceil(still_window_s * frame_rate_hz - 1e-9)))


def noise_sigma_mm(positions: np.ndarray) -> float:
    """Per-axis white-noise σ (mm) of positions (k, 3) of consecutive frames, estimated
    robustly from their second differences (variance 6σ² for white noise): the median of the
    absolute second differences over every axis / (0.6745·√6). 0 with fewer than 3 frames."""
    p = np.asarray(positions, dtype=np.float64)
    if len(p) < 3:
        return 0.0
    d2 = p[2:] - 2.0 * p[1:-1] + p[:-2]
    return float(np.median(np.abs(d2)) / (_MAD * math.sqrt(6.0)))


def stillness(positions: np.ndarray, tol_mm: float | None = None) -> tuple[float, float]:
    """(spread, tolerance) in mm for positions (k, 3) of one body over a window: the spread
    is the RMS distance from their mean; the tolerance ``tol_mm``, or when None
    ``STILL_NOISE_MULTIPLE``·√3·σ̂ (``noise_sigma_mm``) but at least ``STILL_FLOOR_MM``. The
    body is still when spread ≤ tolerance."""
    p = np.asarray(positions, dtype=np.float64)
    spread = float(np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1))))
    if tol_mm is None:
        tol_mm = max(STILL_FLOOR_MM, STILL_NOISE_MULTIPLE * math.sqrt(3.0) * noise_sigma_mm(p))
    return spread, float(tol_mm)


@dataclass
class _Settled:
    """How settling ended: still or not, why not, and the last frame number read."""

    still: bool
    problem: str | None = None
    last_frame: int | None = None


def _window_verdict(window: deque[dict[str, np.ndarray | None]], names: list[str],
                    tol_mm: float | None) -> list[tuple[str, float, float]]:
    """The bodies that are not still over ``window`` (frames of {body: position or None}),
    as (body, spread mm, tolerance mm); empty when every judged body is still."""
    moving = []
    for b in names:
        pts = [p for f in window if (p := f[b]) is not None]
        if len(pts) < _MIN_JUDGED:
            continue
        spread, tol = stillness(np.stack(pts), tol_mm)
        if not spread <= tol:
            moving.append((b, spread, tol))
    return moving


def _usable_position(t: ToolState) -> np.ndarray | None:
    """The tool's position (3,) mm in the tracker frame when it is usable, else None."""
    return t.pose[:3, 3].copy() if t.usable and t.pose is not None else None


def _wait_until_still(tracker: Tracker, settle_s: float, still_window_s: float,
                      tol_mm: float | None, max_frames_factor: float,
                      clock: Callable[[], float]) -> _Settled:
    """Read frames until every body is still over the window, or ``settle_s`` s pass."""
    names = list(tracker.tools)
    rate = max(tracker.frame_rate_hz, 1.0)
    w = window_frames(min(still_window_s, settle_s), tracker.frame_rate_hz)
    window: deque[dict[str, np.ndarray | None]] = deque(maxlen=w)
    deadline = Deadline(settle_s, clock)
    budget = settle_s * rate + w
    moving: list[tuple[str, float, float]] = []
    last = None  # the loop ends by a return, a break, or DeviceTimeout from the tracker
    for fr in tracker.distinct_frames(
            None, timeout_s=settle_s + max_frames_factor * w / rate + 5.0,
            max_reads=int(budget * max_frames_factor + 10) * 50):
        last = fr.frame
        window.append({b: _usable_position(fr.tools[b]) for b in names})
        if len(window) < w:
            continue
        moving = _window_verdict(window, names, tol_mm)
        if not moving:
            return _Settled(True, None, last)
        if deadline.expired():
            break
    why = "; ".join(f"{b} {s:.3f} mm RMS over the last window of {w} frames, tolerance "
                    f"{t:.3f} mm" for b, s, t in moving)
    return _Settled(False, f"not still after {settle_s:g} s ({why})", last)


class _Running:
    """Running mean and spread of one body's positions (mm), about its first position (no
    cancellation at tracker distances of metres)."""

    def __init__(self) -> None:
        self.k = 0
        self.ref: np.ndarray | None = None
        self.s1 = np.zeros(3)
        self.s2 = 0.0

    def add(self, p: np.ndarray) -> None:
        if self.ref is None:
            self.ref = p.copy()
        d = p - self.ref
        self.k += 1
        self.s1 += d
        self.s2 += float(d @ d)

    def sem_mm(self) -> float:
        """Standard error of the mean position: RMS spread / √k (mm); inf before 2 frames."""
        if self.k < 2:
            return math.inf
        m = self.s1 / self.k
        return math.sqrt(max(0.0, self.s2 / self.k - float(m @ m))) / math.sqrt(self.k)


def _collect(robot: Robot, tracker: Tracker, n_samples: int, sem_mm: float | None,
             floor: int, robot_reads: int, max_frames_factor: float,
             skip_frame: int | None
             ) -> tuple[dict[str, list[np.ndarray]], dict[str, int], list[np.ndarray], list[int]]:
    """Read frames (never ``skip_frame``, the last one read while settling) until
    ``n_samples`` frames, or with ``sem_mm`` until every body has ``floor`` usable frames and
    a standard error ≤ sem_mm. Returns (usable poses per body, unusable counts per body,
    robot flange reads, frame numbers)."""
    names = list(tracker.tools)
    got: dict[str, list[np.ndarray]] = {b: [] for b in names}
    flags: dict[str, int] = {b: 0 for b in names}
    runs = {b: _Running() for b in names}
    A_reads: list[np.ndarray] = []
    frames: list[int] = []
    # fixed count: robot reads spread over the n frames; by need: over the floor's frames
    every = max(1, (n_samples if sem_mm is None else floor) // max(1, robot_reads))
    rate = max(tracker.frame_rate_hz, 1.0)
    for fr in tracker.distinct_frames(
            None, timeout_s=max_frames_factor * n_samples / rate + 5.0,
            max_reads=int(max(n_samples * max_frames_factor, n_samples + 10)) * 50):
        if fr.frame == skip_frame:
            continue
        if len(frames) % every == 0 and (sem_mm is None or len(A_reads) < robot_reads):
            A_reads.append(robot.flange_pose())
        frames.append(fr.frame)
        for b in names:
            st = fr.tools[b]
            if st.usable and st.pose is not None:
                got[b].append(st.pose)
                runs[b].add(st.pose[:3, 3])
            else:
                flags[b] += 1
        if len(frames) >= n_samples:
            break
        if sem_mm is not None and all(r.k >= floor and r.sem_mm() <= sem_mm
                                      for r in runs.values()):
            break
    return got, flags, A_reads, frames


def _average(names: list[str], got: dict[str, list[np.ndarray]], A_reads: list[np.ndarray],
             n_frames: int, min_share: float
             ) -> tuple[dict[str, np.ndarray | None], dict[str, int], dict[str, dict[str, float]],
                        dict[str, float], list[str]]:
    """Mean poses, counts, spreads and usable shares per body; the problems found."""
    A = pose_mean(np.stack(A_reads))
    out: dict[str, np.ndarray | None] = {"A": A}
    samples: dict[str, int] = {"A": len(A_reads)}
    spread: dict[str, dict[str, float]] = {"A": spread_of(np.stack(A_reads), A)}
    share: dict[str, float] = {}
    low = []
    for b in names:
        k = len(got[b])
        share[b] = k / n_frames
        samples[b] = k
        if k == 0 or share[b] < min_share:
            out[b] = None
            low.append(f"{b} seen in {k} of {n_frames} frames")
            continue
        P = np.stack(got[b])
        m = pose_mean(P)
        out[b] = m
        spread[b] = spread_of(P, m)
    problems = []
    if low:
        why = ("missing or out of the volume" if all(samples[b] == 0 for b in names
                                                      if out.get(b) is None)
               else "dropouts, partly hidden or at the volume's edge")
        problems.append(f"{', '.join(low)}, below min_share {min_share:g} ({why})")
    return out, samples, spread, share, problems


def sample_pose(robot: Robot, tracker: Tracker, sampling: SamplingConfig,
                sleep: Callable[[float], None] = time.sleep,
                on_phase: Callable[[str], None] | None = None, *,
                clock: Callable[[], float] = time.monotonic) -> PoseSample:
    """Settle, then sample the tracker at one pose as ``sampling`` (the config's
    ``SamplingConfig``, or a run's settings) says. Settling (module docstring): ``settle``
    "still" waits for stillness, at most ``settle_s`` s; "fixed" waits ``settle_s`` s
    (``sleep``); ``settle_s`` 0 not at all. Then ``samples`` distinct frames, or with
    ``sem_mm`` (mm) until every body's standard error of the mean position is ≤ sem_mm (at
    least ``min_samples``, at most ``samples`` frames). The robot's flange pose is read
    alongside ``robot_reads`` of those frames, spread evenly over the n frames (by need: over
    the first ``min_samples``); the robot holds still, and every read is a round trip on some
    controllers. The read budget is bounded (``max_frames_factor``·n reads per distinct frame
    budget and a wall-time limit from the frame rate). The joint angles are read once, after
    sampling (``read_joints``). Each body keeps the frames in which it is usable; a body
    usable in fewer than ``min_share`` of the frames, or a pose never still, makes the sample
    a problem (named). ``on_phase`` hears "settling", then "sampling". ``clock`` (monotonic
    seconds) times the phases and bounds the stillness wait. Settings out of range (the
    config's one check, ``check_sampling``) raise ValueError naming the key."""
    try:
        check_sampling(sampling, "sample_pose", floor_within_cap=False)
    except ConfigError as e:
        raise ValueError(str(e)) from None
    sm = sampling
    n_samples, settle_s, max_frames_factor = sm.samples, sm.settle_s, sm.max_frames_factor
    names = list(tracker.tools)
    if on_phase:
        on_phase("settling")
    t0 = clock()
    settled = _Settled(False)
    if settle_s > 0 and sm.settle == "fixed":
        sleep(settle_s)
    elif settle_s > 0:
        settled = _wait_until_still(tracker, settle_s, sm.still_window_s, sm.still_tol_mm,
                                    max_frames_factor, clock)
    t1 = clock()
    if settled.problem is not None:
        # not still: the pose is a problem; one robot read records where the arm was
        last = settled.last_frame if settled.last_frame is not None else -1
        return PoseSample(A=robot.flange_pose(), bodies={b: None for b in names},
                          samples={"A": 1, **{b: 0 for b in names}}, spread={},
                          share={b: 0.0 for b in names}, frames=0, first_frame=last,
                          last_frame=last, problem=settled.problem,
                          flags={b: 0 for b in names}, settling_s=t1 - t0)
    if on_phase:
        on_phase("sampling")
    got, flags, A_reads, frames = _collect(robot, tracker, n_samples, sm.sem_mm,
                                           min(sm.min_samples, n_samples), sm.robot_reads,
                                           max_frames_factor, settled.last_frame)
    means, samples, spread, share, problems = _average(names, got, A_reads, len(frames),
                                                       sm.min_share)
    A = means.pop("A")
    assert A is not None
    return PoseSample(A=A, bodies=means, samples=samples, spread=spread, share=share,
                      frames=len(frames), first_frame=frames[0], last_frame=frames[-1],
                      problem="; ".join(problems) or None, flags=flags,
                      settling_s=t1 - t0, sampling_s=clock() - t1, still=settled.still,
                      joints=read_joints(robot))
