"""Acquisition overhead on the mock rig, through the real drivers and wire protocols.

    .venv/bin/python benchmarks/acquisition.py [--robot ur|denso] [--only realtime|fast]

(a) Real-time clock: a short plan (10 poses × 100 samples at 60 Hz, a fixed 1 s settle).
    Prints the wall time divided by the physical minimum (motion + settle + samples / frame
    rate, per pose). Target ≤ 1.05. The motion is each mock's law (``tmscal.motion``'s
    trapezoid at the config's speed and acceleration caps; the UR's rotation also capped at
    4× the same numbers in rad/s and rad/s², as a movel, ``tmscal.mocks.ur.motion``).
(b) Fast clock: 500 poses × 100 samples end to end (mock in a child process, Polaris over
    loopback TCP and over a pty). Target under 60 s on a 2-core machine.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from figures import record

from tmscal.acquisition.run import acquire
from tmscal.config import load_config
from tmscal.mocks.launch import spawn_mock_rig
from tmscal.mocks.ur.motion import ROTATION_FACTOR
from tmscal.motion import move_duration
from tmscal.session import read_session

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def make_config(tmp: Path, robot: str, clock: str, poses: int, samples: int,
                settle: float) -> Path:
    base = "mock-ur-polaris.yaml" if robot == "ur" else "mock-denso-polaris.yaml"
    data = yaml.safe_load((CONFIGS / base).read_text())
    data["tracker"]["tools"] = {k: str(CONFIGS / v) for k, v in data["tracker"]["tools"].items()}
    data["plan"]["poses"] = poses
    # a fixed settle: the physical minimum below counts settle_s in full at every pose (with
    # the default "still" settle, sampling starts as soon as the bodies are still)
    data["sampling"].update(samples=samples, settle_s=settle, settle="fixed")
    data["mock"]["clock"] = clock
    if robot == "ur":
        data["robot"]["host"] = "127.0.0.61" if clock == "real" else "127.0.0.62"
    else:
        data["robot"]["port"] = 0
    p = tmp / f"bench-{robot}-{clock}.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def run(cfg_path: Path, out: Path, transport: str) -> tuple[float, object]:
    cfg = load_config(cfg_path)
    with spawn_mock_rig(cfg_path, transport=transport) as mp:
        host, _, port = mp.endpoints["robot"].partition(":")
        t0 = time.perf_counter()
        res = acquire(cfg, out, tracker_port=mp.endpoints["tracker"], robot_host=host,
                      robot_port=int(port) if port else None)
        return time.perf_counter() - t0, res


def realtime(tmp: Path, robot: str) -> None:
    cfg_path = make_config(tmp, robot, "real", 10, 100, 1.0)
    cfg = load_config(cfg_path)
    out = tmp / "rt.jsonl"
    wall, res = run(cfg_path, out, "pty")
    s = read_session(out)
    p0 = np.asarray(s.header["plan"]["p0"])
    cmd = np.stack([p0] + [p.commanded for p in s.poses])
    v, acc = cfg.robot.speed_mm_s, cfg.robot.accel_mm_s2
    # the mocks' motion law: a trapezoid at the caps; the UR's movel caps its rotation too, at
    # ROTATION_FACTOR × the same numbers in rad/s and rad/s²
    rot = ((math.degrees(ROTATION_FACTOR * v / 1e3), math.degrees(ROTATION_FACTOR * acc / 1e3))
           if robot == "ur" else (None, None))
    motion = float(sum(move_duration(cmd[i], cmd[i + 1], v, acc, *rot)
                       for i in range(len(cmd) - 1)))
    per_pose = cfg.sampling.settle_s + cfg.sampling.samples / cfg.tracker.frame_rate_hz
    minimum = motion + per_pose * len(s.poses)
    print(f"(a) real time, {robot}: {len(s.poses)} poses × {cfg.sampling.samples} samples "
          f"at {cfg.tracker.frame_rate_hz:g} Hz, settle {cfg.sampling.settle_s:g} s")
    print(f"    wall {wall:.2f} s (incl. connect), acquisition loop {res.elapsed_s:.2f} s; "
          f"physical minimum {minimum:.2f} s (motion {motion:.2f} s)")
    print(f"    ratio wall/minimum: {wall / minimum:.3f}   loop/minimum: "
          f"{res.elapsed_s / minimum:.3f}   (target ≤ 1.05)")
    record("acquisition", {f"{robot}_rt_wall_over_min": round(wall / minimum, 3),
                           f"{robot}_rt_loop_over_min": round(res.elapsed_s / minimum, 3)})


def fast(tmp: Path, robot: str) -> None:
    cfg_path = make_config(tmp, robot, "fast", 500, 100, 0.0)
    for transport in ("tcp", "pty"):
        out = tmp / f"fast-{transport}.jsonl"
        wall, res = run(cfg_path, out, transport)
        print(f"(b) fast clock, {robot}, Polaris over {transport}: 500 poses × 100 samples "
              f"in {wall:.1f} s ({res.recorded} recorded, {res.skipped} skipped; "
              f"{wall / 50000 * 1e3:.2f} ms per frame)   (target < 60 s)")
        record("acquisition", {f"{robot}_fast_{transport}_s": round(wall, 1)})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", choices=["ur", "denso"], default="ur")
    ap.add_argument("--only", choices=["realtime", "fast"], default=None)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        if a.only in (None, "realtime"):
            realtime(Path(d), a.robot)
        if a.only in (None, "fast"):
            fast(Path(d), a.robot)
    load = os.getloadavg()
    print(f"load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f} (1, 5, 15 min)")
    record("acquisition", {f"{a.robot}_load_1min": round(load[0], 2)})


if __name__ == "__main__":
    main()
