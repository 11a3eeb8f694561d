"""A protocol-level Universal Robots controller that serves a ``SimRig``.

The unmodified ``ur_rtde`` client library (``RTDEControlInterface``, ``RTDEReceiveInterface``,
``DashboardClient``) drives it, with the library's default flags (script upload) and with
``flags=0`` (no upload). Three TCP servers on one loopback address:

* **30004 RTDE**: protocol negotiation (``V``), controller version (``v``), output recipe
  (``O``) and input recipes (``I``, numbered 1, 2, 3 … per connection, as ur_rtde expects),
  start/pause (``S``/``P``), data packages (``U``) both ways. Each connection streams its output
  recipe from its own thread at the requested frequency, on the real-time and on the fast clock
  alike (only *motion* is instant on the fast clock).
* **29999 dashboard** (``dashboard``): banner, ``PolyscopeVersion``, ``get serial number``,
  ``is in remote control``, ``robotmode``, ``safetystatus``, ``stop`` (→ ``Stopped``),
  ``play``, ``pause``, ``unlock protective stop``, ``power on``/``power off``/``brake
  release`` and the other status queries; unknown commands get the real server's ``could not
  understand: '…'``; in Local Control the commands that act on the robot get the real
  server's "Command is not allowed due to safety reasons, …".
* **30003 script**: the uploaded URScript program is accepted (kept in ``last_script``) and
  the emulated ``rtde_control`` script starts (``runtime_state`` 2, PLAYING) — only on a
  powered, brake-released robot (robot mode RUNNING) without a protective stop, in remote
  control, as on a real controller; otherwise it is dropped and nothing runs.
* The **External Control URCap** (``urcap``, with ``urcap_port``): Play fetches the script
  from ur_rtde's script sender on the PC (``FLAG_USE_EXT_UR_CAP``).

The emulated control script follows ur_rtde's register handshake (``controller``). A linear
move puts the rig's flange at ``pose_from_rotvec(pose)``; in real time it runs on the
trapezoidal profile of :mod:`tmscal.motion` at movel's v and a (rotation: 4·v rad/s, 4·a
rad/s², docs/devices.md) and the flange follows the path; on the fast clock it is immediate
(its modelled duration is still recorded in ``last_motion_s``). ``actual_TCP_pose`` is
``rotvec_pose_from_matrix(rig.reported_flange() · tcp_offset)``: the TCP offset is zero unless
``URMock(tcp_offset=…)`` sets one (``getTCPOffset`` answers it, and ``moveL`` then moves the TCP
on the straight line). Every move the controller starts is kept in ``trajectory`` (its
``Motion`` gives the flange at any time of the modelled profile, on the fast clock too).
Without ``mock.kinematics`` joint values are placeholders; with it, the rig's joints
(docs/selfcal.md).

Because ur_rtde's ports are fixed, each mock binds its own loopback address (127.0.0.2,
127.0.0.3, …), so several mocks (and tests) can run side by side.

Hostile input: an output recipe frequency that is not finite or outside
[``MIN_FREQUENCY_HZ``, ``MAX_FREQUENCY_HZ``] is refused (``O`` reply with recipe id 0 and no
types; a later ``S`` answers 0, not started, and nothing streams). A move whose pose, speed or
acceleration is not finite, or whose speed or acceleration is not positive, is a runtime error
of the control script, as on a real controller: the program stops (runtime_state 1), the
flange stays where it was, and nothing non-finite reaches the rig; ``play`` (dashboard) or a
new script upload starts it again. Joint targets must be finite too.

Faults (``URFaults``): a protective stop during the k-th move (safety mode 3,
``safety_status_bits`` bit 2, the flange stops half-way and the control script stops,
runtime_state 1, as ur_rtde's ``reuploadScript`` documentation describes; cleared with the
dashboard's ``unlock protective stop``, after which only a new script upload or ``play`` runs
it again), a power-off during the k-th move (robot mode POWER_OFF, the program stops), and a
dropped connection at the k-th move (every client socket is closed and
the listeners close). Moves are counted from 1 over the mock's life (moveL, moveJ, moveL_FK,
moveJ_IK).

Modules: ``rtde`` (the RTDE wire codec), ``controller`` (the simulated controller state
machine), ``motion`` (a linear move), ``dashboard`` (the dashboard's command table),
``urcap`` (the External Control URCap), ``servers`` (the RTDE, dashboard and script
servers; ``URMock``).
"""

from __future__ import annotations

from .controller import (
    CMD_MOVEJ,
    CMD_MOVEJ_IK,
    CMD_MOVEL,
    CMD_MOVEL_FK,
    CMD_NO_CMD,
    CMD_STOP_SCRIPT,
    CMD_STOPJ,
    CMD_STOPL,
    CMD_WATCHDOG,
    HOME_Q,
    JOINT_RUNNING_MODE,
    ROBOT_MODE_IDLE,
    ROBOT_MODE_NAMES,
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_RUNNING,
    RUNTIME_PAUSED,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    SAFETY_NORMAL,
    SAFETY_PROTECTIVE_STOP,
    URController,
    URFaults,
)
from .rtde import PackageType, Recipe, rtde_type
from .servers import (
    DASHBOARD_PORT,
    MAX_FREQUENCY_HZ,
    MIN_FREQUENCY_HZ,
    RTDE_PORT,
    SCRIPT_PORT,
    URMock,
)

__all__ = [
    "CMD_MOVEJ", "CMD_MOVEJ_IK", "CMD_MOVEL", "CMD_MOVEL_FK", "CMD_NO_CMD", "CMD_STOPJ",
    "CMD_STOPL", "CMD_STOP_SCRIPT", "CMD_WATCHDOG", "DASHBOARD_PORT", "HOME_Q",
    "JOINT_RUNNING_MODE", "MAX_FREQUENCY_HZ", "MIN_FREQUENCY_HZ", "PackageType", "Recipe",
    "ROBOT_MODE_IDLE", "ROBOT_MODE_NAMES", "ROBOT_MODE_POWER_OFF", "ROBOT_MODE_RUNNING",
    "RTDE_PORT", "RUNTIME_PAUSED", "RUNTIME_PLAYING", "RUNTIME_STOPPED",
    "SAFETY_NORMAL", "SAFETY_PROTECTIVE_STOP", "SCRIPT_PORT", "URController", "URFaults",
    "URMock", "rtde_type",
]
