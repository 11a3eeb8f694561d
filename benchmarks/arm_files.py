"""The shipped arm files and the URDF reader (docs/kinematics.md, "Arm files"): each shipped
arm's flange at q = 0 (mm, base frame), and the largest forward-kinematics difference (mm, over
1000 random joint vectors) between the registry's UR5e and FR3 and the same arms read from a
URDF (the test's, tests/unit/test_arm_files.py) and from the UR5e arm file of the docs.

    python benchmarks/arm_files.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from figures import record  # noqa: E402

from tests.unit.test_arm_files import FRANKA, UR5E, UR5E_ARM_FILE, urdf_text  # noqa: E402
from tmscal.calib.kinematics import arm_by_name, base_from_flange  # noqa: E402
from tmscal.formats.armdef import resolve_arm, shipped_arm_names  # noqa: E402
from tmscal.formats.kinfile import parse_kinematics  # noqa: E402
from tmscal.formats.textfile import load_text  # noqa: E402
from tmscal.formats.urdf import parse_urdf  # noqa: E402


def main() -> None:
    figures: dict[str, float] = {}
    print("shipped arm files, the flange at q = 0 (mm, base frame):")
    for name in shipped_arm_names():
        arm = resolve_arm(name).arm
        t = base_from_flange(arm, np.zeros(arm.n_joints))[:3, 3]
        print(f"  {name:16s} {arm.n_joints} joints  ({t[0]:8.1f}, {t[1]:8.1f}, {t[2]:8.1f})")
        for k, v in zip("xyz", t, strict=True):
            figures[f"{name}_zero_{k}_mm"] = round(float(v), 1)
    rng = np.random.default_rng(1)
    cases = (("ur5e_urdf", parse_urdf(urdf_text(UR5E), "ur5e.urdf"), "ur5e"),
             ("fr3_urdf", parse_urdf(urdf_text(FRANKA, base="panda_link0",
                                               flange="panda_link8"), "fr3.urdf",
                                     "panda_link0", "panda_link8"), "fr3"),
             ("ur5e_arm_file", parse_kinematics(load_text(UR5E_ARM_FILE, "ur5e.yaml"),
                                                "ur5e.yaml").model, "ur5e"))
    print("forward kinematics against the registry (max |ΔT|, 1000 joint vectors):")
    for key, arm, reg in cases:
        ref = arm_by_name(reg)
        lim = ref.joint_limits_rad
        q = rng.uniform(lim[:, 0], lim[:, 1], (1000, ref.n_joints))
        d = float(np.abs(base_from_flange(arm, q) - base_from_flange(ref, q)).max())
        print(f"  {key:14s} vs {reg:5s} {d * 1e12:.2f} × 10⁻¹² mm")
        figures[f"{key}_max_e12_mm"] = round(d * 1e12, 2)
    record("arm_files", figures)


if __name__ == "__main__":
    main()
