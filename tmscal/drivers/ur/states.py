"""UR controller states as RTDE and the dashboard server report them (UR's "Real-Time Data
Exchange (RTDE) Guide" and "Dashboard Server e-Series, port 29999"), and what the operator
does at the pendant for each robot mode that cannot run the control script."""

from __future__ import annotations

import re

__all__ = ["MODE_ACTION", "ROBOT_MODES", "ROBOT_MODE_RUNNING", "RUNTIME_STATES", "SAFETY_MODES",
           "dashboard_value", "remote_check_applies"]

#: UR safety modes (RTDE ``safety_mode``).
SAFETY_MODES = {
    1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
    10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
    13: "SYSTEM_THREE_POSITION_ENABLING_STOP",
}
#: UR robot modes (RTDE ``robot_mode``; the dashboard's ``robotmode`` names them alike).
ROBOT_MODES = {
    -1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
    4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE",
}
ROBOT_MODE_RUNNING = 7
#: What the operator does at the pendant for a robot mode other than RUNNING.
MODE_ACTION = {
    "POWER_OFF": "the robot is powered off: power it on and release the brakes at the pendant",
    "POWER_ON": "the robot is powering on: wait, then release the brakes at the pendant",
    "IDLE": "the robot's brakes are engaged: release them at the pendant",
    "BOOTING": "the robot is booting: wait for it, then power it on at the pendant",
}
#: UR program runtime states (RTDE ``runtime_state``).
RUNTIME_STATES = {0: "STOPPING", 1: "STOPPED", 2: "PLAYING", 3: "PAUSING", 4: "PAUSED",
                  5: "RESUMING"}


def dashboard_value(reply: str | None) -> str | None:
    """``NORMAL`` from the dashboard's ``Safetystatus: NORMAL`` (None stays None)."""
    if reply is None:
        return None
    return reply.split(":")[-1].strip().upper() or None


def remote_check_applies(version: str | None) -> bool:
    """Whether the dashboard knows ``is in remote control``: PolyScope 5.6 and later (what
    ur_rtde's own check requires; ``URSoftware 5.11.0.108249 (…)`` → True)."""
    m = re.search(r"(\d+)\.(\d+)\.\d+", version or "")
    return m is not None and int(m.group(1)) == 5 and int(m.group(2)) > 5
