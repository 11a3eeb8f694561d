"""Sampling at one pose: settle, collect N distinct tracker frames with the robot pose read
alongside, drop frames in which a body is missing or out of volume, average.

Averages: translations by arithmetic mean, rotations by the chordal L2 mean. Spreads: RMS
distance of the samples' origins from the mean (mm) and RMS rotation angle from the mean
rotation (deg). Frames: A = base_from_flange (robot), tracker_from_<body> per tool; 4×4 mm.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..drivers.base import Robot, Tracker
from ..geometry import angle_between, pose_mean

log = logging.getLogger(__name__)

__all__ = ["PoseSample", "sample_pose", "spread_of"]


@dataclass
class PoseSample:
    """The result at one pose: averaged A and per-body poses (None when a body had too few
    usable frames), sample counts, spreads, the share of usable frames per body, and the
    reason when the pose is unusable."""

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


def spread_of(poses: np.ndarray, mean: np.ndarray) -> dict[str, float]:
    """RMS translation (mm) and rotation (deg) of poses (k, 4, 4) about their mean."""
    dt = np.linalg.norm(poses[:, :3, 3] - mean[:3, 3], axis=1)
    da = np.degrees(angle_between(mean, poses))
    return {"trans_mm": float(np.sqrt((dt ** 2).mean())),
            "rot_deg": float(np.sqrt((da ** 2).mean()))}


def sample_pose(robot: Robot, tracker: Tracker, n_samples: int, settle_s: float = 1.0,
                min_share: float = 0.8, max_frames_factor: float = 3.0,
                sleep: Any = time.sleep, robot_reads: int = 10,
                on_phase: Callable[[str], None] | None = None) -> PoseSample:
    """Wait ``settle_s`` seconds, then read tracker frames until ``n_samples`` distinct frame
    numbers were seen (bounded: at most ``max_frames_factor``·n reads per distinct frame
    budget and a wall-time limit from the frame rate), reading the robot's flange pose
    alongside ``robot_reads`` of those frames, spread evenly (the robot holds still; every
    read is a round trip on some controllers). Each body keeps the frames in which it is
    usable; a body with fewer than ``min_share``·n usable frames makes the sample a problem
    (named). ``on_phase`` hears "settling" before the wait and "sampling" after it."""
    every = max(1, n_samples // max(1, robot_reads))
    if on_phase:
        on_phase("settling")
    if settle_s > 0:
        sleep(settle_s)
    if on_phase:
        on_phase("sampling")
    names = list(tracker.tools)
    got: dict[str, list[np.ndarray]] = {b: [] for b in names}
    flags: dict[str, int] = {b: 0 for b in names}
    A_reads: list[np.ndarray] = []
    frames: list[int] = []
    rate = max(tracker.frame_rate_hz, 1.0)
    for fr in tracker.distinct_frames(
            n_samples, timeout_s=max_frames_factor * n_samples / rate + 5.0,
            max_reads=int(max(n_samples * max_frames_factor, n_samples + 10)) * 50):
        if len(frames) % every == 0:
            A_reads.append(robot.flange_pose())
        frames.append(fr.frame)
        for b in names:
            st = fr.tools[b]
            if st.usable and st.pose is not None:
                got[b].append(st.pose)
            else:
                flags[b] += 1
    A = pose_mean(np.stack(A_reads))
    out_bodies: dict[str, np.ndarray | None] = {}
    samples: dict[str, int] = {"A": len(A_reads)}
    spread: dict[str, dict[str, float]] = {"A": spread_of(np.stack(A_reads), A)}
    share: dict[str, float] = {}
    problems = []
    for b in names:
        k = len(got[b])
        share[b] = k / n_samples
        samples[b] = k
        if k == 0 or share[b] < min_share:
            out_bodies[b] = None
            problems.append(f"{b} usable in {k} of {n_samples} frames "
                            f"(< {min_share:.0%}: missing or out of volume)")
            continue
        P = np.stack(got[b])
        m = pose_mean(P)
        out_bodies[b] = m
        spread[b] = spread_of(P, m)
    return PoseSample(A=A, bodies=out_bodies, samples=samples, spread=spread, share=share,
                      frames=len(frames), first_frame=frames[0], last_frame=frames[-1],
                      problem="; ".join(problems) or None, flags=flags)
