"""``tmscal selfcal``: kinematic self-calibration of the robot arm from a wrist force-torque
sensor (Joubair et al. 2016; docs/selfcal.md).

The group lives here with ``simulate`` (the simulation study, no devices); ``acquire`` and
``identify`` (the rig side) register on the same group from :mod:`tmscal.cli.selfcal_rig`.
"""

from __future__ import annotations

from . import main


@main.group()
def selfcal() -> None:
    """Kinematic self-calibration from a wrist force-torque sensor (Joubair et al. 2016).

    The gravity wrench that a sensor at the wrist reads in many arm configurations depends on
    the arm's kinematic parameters (joint offsets, link twists, base and sensor orientation)
    and on the tool's mass and centre of gravity; fitting it identifies the parameters it
    observes, without external measuring equipment. Joint angles are rad inside, lengths mm,
    forces N, torques N·m (docs/selfcal.md).

    \b
      tmscal selfcal simulate              the simulation study (identifiable parameters,
                                           TCP error before/after, pose-selection indices)
      tmscal selfcal acquire CONFIG -o S   move through selected configurations, record
                                           joints and wrenches
      tmscal selfcal identify S -o K.yaml  fit a session, write the calibrated parameters
    """
