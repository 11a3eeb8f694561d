"""Tracker benchmark: our NDI driver reading from the Polaris mock over a pty.

1. Throughput on the fast clock: frames per second the driver reads with BX and TX
   (target ≥ 1,000/s). The mock runs in a separate process, as a real tracker would.
2. Real time: a Spectra-rate (60 Hz) mock polled as fast as possible for ``--seconds``
   seconds; reports the share of the frames the device produced that the driver saw, and
   any gaps in the frame numbers (target: all of them, no gaps).

Usage: ``python benchmarks/tracker.py [--seconds 10] [--fast-seconds 3]``
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time
from pathlib import Path

import numpy as np
from figures import record

from tmscal.drivers.ndi.tracker import NDITracker

ROOT = Path(__file__).resolve().parents[1]
ROMS = {"marker": str(ROOT / "configs/tools/marker-8700340.rom"),
        "probe": str(ROOT / "configs/tools/probe-8700340.rom")}


def _serve(fast: bool, conn, stop) -> None:
    from tmscal.mocks.clock import FAST, REAL_TIME
    from tmscal.mocks.polaris import PolarisMock
    from tmscal.sim.rig import TMS_RIG_P0, SimRig, tms_rig_truth
    rig = SimRig(tms_rig_truth(), rng=np.random.default_rng(0), start=TMS_RIG_P0)
    with PolarisMock(rig, ROMS, model="spectra", clock=FAST if fast else REAL_TIME) as m:
        conn.send(m.start_pty())
        stop.wait(600)


class _Mock:
    def __init__(self, fast: bool) -> None:
        ctx = mp.get_context("fork")
        self.conn, child = ctx.Pipe()
        self.stop = ctx.Event()
        self.proc = ctx.Process(target=_serve, args=(fast, child, self.stop), daemon=True)
        self.proc.start()
        self.path = self.conn.recv()

    def close(self) -> None:
        self.stop.set()
        self.proc.join(5)


def throughput(seconds: float) -> dict[str, float]:
    out = {}
    mock = _Mock(fast=True)
    try:
        for reply in ("bx", "tx"):
            with NDITracker(mock.path, ROMS, reply=reply, reset=False) as tr:
                n, t0 = 0, time.perf_counter()
                while time.perf_counter() - t0 < seconds:
                    tr.read()
                    n += 1
                out[reply] = n / (time.perf_counter() - t0)
    finally:
        mock.close()
    return out


def real_time(seconds: float) -> tuple[int, int, int, int]:
    """(reads, distinct frames, frames produced in the span, gaps)."""
    mock = _Mock(fast=False)
    try:
        with NDITracker(mock.path, ROMS, reply="bx", reset=False) as tr:
            frames, reads, t0 = [], 0, time.perf_counter()
            while time.perf_counter() - t0 < seconds:
                frames.append(tr.read().frame)
                reads += 1
    finally:
        mock.close()
    distinct = sorted(set(frames))
    span = distinct[-1] - distinct[0] + 1
    gaps = sum(1 for a, b in zip(distinct, distinct[1:], strict=False) if b - a > 1)
    return reads, len(distinct), span, gaps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--fast-seconds", type=float, default=3.0)
    a = ap.parse_args()
    fps = throughput(a.fast_seconds)
    print(f"fast clock, pty, mock in its own process: BX {fps['bx']:.0f} frames/s, "
          f"TX {fps['tx']:.0f} frames/s (target >= 1000)")
    reads, distinct, span, gaps = real_time(a.seconds)
    print(f"real time 60 Hz over {a.seconds:g} s: {reads} reads, {distinct} distinct frames of "
          f"{span} produced ({100 * distinct / span:.1f} %), {gaps} gaps in frame numbers "
          f"({distinct / a.seconds:.1f} distinct frames/s)")
    load = os.getloadavg()
    print(f"load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f} (1, 5, 15 min)")
    record("tracker", {"load_1min": round(load[0], 2), "bx_fps": round(fps["bx"]),
                       "tx_fps": round(fps["tx"]), "rt_seconds": a.seconds,
                       "rt_distinct_frames": distinct, "rt_frames_produced": span, "rt_gaps": gaps,
                       "rt_seen_pct": round(100 * distinct / span, 1)})


if __name__ == "__main__":
    main()
