"""The Franka demo, timed: ``tmscal demo --config configs/mock-franka-polaris.yaml --poses 20
--json`` (franky against franky-sim and the mock Polaris, in real time) in a subprocess.

    .venv/bin/python benchmarks/franka_demo.py [--poses 20] [--config C]

Prints what the demo's JSON says (the poses solved and skipped, QR36's errors of X, Y and Z's
translation against the mock rig's truth, mm, and the coil placement error, mm) and the wall
time of the whole command (s: starting the mocks, acquiring, solving). Needs franky and
franky-sim (``pip install 'tmscal[franka]'``); takes about a minute.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from figures import record

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "mock-franka-polaris.yaml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=20)
    ap.add_argument("--config", type=Path, default=CONFIG)
    a = ap.parse_args()
    cmd = [sys.executable, "-m", "tmscal.cli", "demo", "--config", str(a.config),
           "--poses", str(a.poses), "--json"]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=1200)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"tmscal demo failed ({p.returncode}):\n{p.stderr[-3000:]}")
    res = json.loads(p.stdout.strip().splitlines()[-1])
    t = res["truth"]
    print(f"tmscal demo --config {a.config.name} --poses {a.poses} --json: {res['method']}, "
          f"{res['n_solve']} poses solved, {res['n_skipped']} skipped, in {wall:.0f} s")
    print(f"  against the mock rig's truth: X {t['X']['trans_mm']:.3f} mm, "
          f"Y {t['Y']['trans_mm']:.3f} mm, Z {t['Z']['trans_mm']:.3f} mm; "
          f"coil placement {t['coil_placement_mm']:.4f} mm")
    record("franka_demo", {
        "poses": a.poses, "solved": res["n_solve"], "skipped": res["n_skipped"],
        "x_trans_mm": round(t["X"]["trans_mm"], 3), "y_trans_mm": round(t["Y"]["trans_mm"], 3),
        "z_trans_mm": round(t["Z"]["trans_mm"], 3),
        "coil_placement_mm": round(t["coil_placement_mm"], 4), "wall_s": round(wall)})


if __name__ == "__main__":
    main()
