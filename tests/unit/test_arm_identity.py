"""What a controller says about itself, turned into a registered arm name (docs/kinematics.md,
"Which arm the controller is"): the UR dashboard's robot model, PolyScope version and serial
number; a DENSO robot's ``@TYPE_NAME``; the robot name in the URDF a Franka controller sends.
Unknown or ambiguous answers give None, never a guess."""

from __future__ import annotations

import pytest

from tests.rigs import unique_host
from tmscal.drivers.denso.arm import denso_arm
from tmscal.drivers.franka.robot import arm_from_urdf
from tmscal.drivers.ur.arm import ur_arm, ur_generation


@pytest.mark.parametrize("version, serial, generation", [
    ("URSoftware 5.11.0.108249 (Mar 24 2021)", None, "e-Series"),
    ("5.11.0.108249", None, "e-Series"),
    ("3.15.8.106339", None, "CB3"),
    ("URSoftware 3.7.0.40195 (Jun 08 2018)", "20185500571", "CB3"),   # the software decides
    ("URSoftware 10.7.0 (2025)", None, "e-Series"),                 # PolyScope X
    (None, "2016351864", "CB3"),           # YYYY G S NNNN: G = 3 (a CB3 UR5)
    (None, "20185500000", "e-Series"),     # YYYY G S NNNNN: G = 5 (a UR5e)
    (None, "20215200001", "e-Series"),     # a 12.5 kg UR10e
    (None, "PV25RT12345", None),           # the 2025 format tells nothing here
    (None, None, None),
    ("URSoftware 4.0", "garbage", None),
])
def test_ur_generation(version, serial, generation):
    assert ur_generation(version, serial) == generation


@pytest.mark.parametrize("model, version, serial, arm", [
    ("UR5", "5.11.0.108249", "20185500001", "ur5e"),
    ("UR5", "3.15.8.106339", None, "ur5"),
    ("UR5", None, "2016351864", "ur5"),
    ("UR5", None, None, None),               # a UR5 or a UR5e: not told
    ("UR3", "3.15.8", None, "ur3"),
    ("UR3", "5.9.4", None, "ur3e"),
    ("UR10", "5.11", None, "ur10e"),
    ("UR10", "3.12", None, "ur10"),
    ("UR16", None, None, "ur16e"),           # only ever an e-Series
    ("UR20", "5.14", None, "ur20"),
    ("UR5e", None, None, "ur5e"),            # an answer that names the generation itself
    (" UR10 \n", "5.11", None, "ur10e"),
    ("UR30", "5.15", None, None),            # not registered
    ("UR16", "3.15", None, None),            # no CB3 UR16
    (None, "5.11", "20185500001", None),     # no model answer
    ("", "5.11", None, None),
])
def test_ur_arm(model, version, serial, arm):
    assert ur_arm(model, version, serial) == arm


@pytest.mark.parametrize("type_name, arm", [
    ("VS-060", "vs060"), ("vs060", "vs060"), ("VS-060A3-AV6-NNN-NNN", "vs060"),
    ("COBOTTA", "cobotta"), ("cobotta", "cobotta"),
    ("VS-087A3", None), ("tmscal b-CAP mock (no DENSO arm)", None), ("", None), (None, None),
    (42, None),
])
def test_denso_arm(type_name, arm):
    assert denso_arm(type_name) == arm


@pytest.mark.parametrize("urdf, arm", [
    ('<?xml version="1.0"?>\n<robot name="fr3">\n  <link name="base"/>\n</robot>', "fr3"),
    ("<robot xmlns:xacro='http://www.ros.org/wiki/xacro' name='panda'><link/></robot>", "panda"),
    ('<robot name="fr3v2"/>', None),
    ('<robot name="kuka_iiwa"/>', None),
    ("", None), (None, None), (b'<robot name="fr3"/>', None),
])
def test_franka_arm_from_urdf(urdf, arm):
    assert arm_from_urdf(urdf) == arm


def test_the_franka_mock_takes_only_the_arm_franky_sim_simulates():
    from tmscal.mocks.franka import FrankaMock
    from tmscal.sim import TMS_RIG_P0, Noise, SimRig, make_arm, tms_rig_truth

    rig = SimRig(tms_rig_truth(), noise=Noise(), start=TMS_RIG_P0, arm=make_arm("ur5e", "none", 0))
    with pytest.raises(ValueError, match="franky-sim simulates an FR3.*not ur5e"):
        FrankaMock(rig, host=unique_host())
