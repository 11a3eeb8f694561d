"""The arm's kinematics estimated on recorded laser-tracker data of a real UR10 (docs/kinematics.md,
"Laser trackers and 6D probes"): tests/data/ipa-ur10-leica-C (2,773 random poses measured with
a Leica T-Mac; MIT licence; its README gives the conventions), imported with `tmscal import`.

    .venv/bin/python benchmarks/laser_tracker.py [--train 30,100,300] [--test 1000]

For each training size n: the first n poses train, the LAST ``--test`` poses of the file are
held out (the same poses for every n, none of them trained on). Printed: the held-out mean
translation error e_t (mm) and rotation error θ (deg) of QR24 (raw matrices, the nominal
arm), ml on the nominal arm (rigid hand/eye and robot/world), and ml with the arm's
kinematics estimated (``--kinematics estimate``, level chosen by held-out error on the
training poses), with the level chosen and the fit's time (s, this machine, everything from
the session to the calibration). The issue's goal: ≤ 0.3 mm held out with ≤ 100 training
poses.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from figures import record

from tmscal.calib.kinematics import arm_by_name
from tmscal.formats.campaign import Columns, campaign_header, campaign_records, read_campaign
from tmscal.session import read_session, write_session
from tmscal.solving.solve import solve

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "ipa-ur10-leica-C"
JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
          "wrist_2_joint", "wrist_3_joint")
COLUMNS = Columns(joints=JOINTS, position=("measurement_x", "measurement_y", "measurement_z"),
                  rotation=("measurement_rx", "measurement_ry", "measurement_rz"),
                  rotation_kind="euler:XYZ")
RUNS = (("qr24 (nominal arm)", "qr24", None), ("ml (nominal arm)", "ml", None),
        ("ml + estimated arm", "ml", "estimate"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--train", default="30,100,300")
    ap.add_argument("--test", type=int, default=1000)
    a = ap.parse_args()
    arm = arm_by_name("ur10")
    c = read_campaign(DATA / "measurements_random_poses.csv", COLUMNS, ";", ",")
    recs = campaign_records(c, arm)
    header = campaign_header(c, arm, COLUMNS, "Leica T-Mac")
    n = len(recs)
    print(f"real UR10, Leica laser tracker: {n} poses; held out: the last {a.test}")
    print(f"  {'train':>6}  {'method':<22}{'e_t mm':>9}{'θ deg':>9}{'level':>9}{'time s':>8}")
    fig: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as d:
        for m in (int(x) for x in a.train.split(",")):
            # the first m poses, then the held-out ones: solve's train=m holds out the rest
            sub = [replace(r, index=i) for i, r in enumerate(recs[:m] + recs[n - a.test:])]
            path = Path(d) / f"s{m}.jsonl"
            write_session(path, header, sub, overwrite=True)
            s = read_session(path)
            for name, method, kin in RUNS:
                t0 = time.perf_counter()
                res = solve(s, method=method, kinematics=kin, train=m)
                dt = time.perf_counter() - t0
                assert res.n_test == a.test
                e_t, th = float(res.errors["e_t_mm"]), float(res.errors["theta_t_deg"])
                level = (res.arm or {}).get("level", "") if kin else ""
                print(f"  {m:>6}  {name:<22}{e_t:>9.3f}{th:>9.4f}{level:>9}{dt:>8.1f}")
                key = method + ("_arm" if kin else "")
                fig[f"train{m}_{key}_e_t_mm"] = round(e_t, 3)
    record("laser_tracker", fig)


if __name__ == "__main__":
    main()
