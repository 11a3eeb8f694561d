"""A DENSO RC8 b-CAP server (TCP, loopback only) that serves a ``SimRig``: ``DensoMock``
(``mock.py``: the server), its controller (``controller.py``: state, ``DensoFaults`` and one
handler per b-CAP function) and request arguments (``args.py``).

What it models (enough for tmscal's driver and DENSO's own b-CAP clients):

* Service_Start / Service_Stop (``WDT=<ms>`` in the option turns on S_EXECUTING keep-alives;
  0 turns them off, other values outside 10..3,600,000 ms get E_INVALIDARG),
  Controller_Connect / Disconnect / GetRobot / GetRobotNames / GetVariable / Execute
  (``GetErrorDescription``, ``ClearError``, ``ManualReset``), Robot_Execute (TakeArm,
  GiveArm, Motor, ExtSpeed, CurPos, CurJnt), Robot_Move (comp 1 = MOVE P, 2 = MOVE L; pose as text
  ``"@E P(x, y, z, rx, ry, rz, fig)"`` or VARIANT array ``[[x, …, fig], "P", "@E"]``; options
  ``SPEED=<percent>``, ``ACCEL=<percent>``, ``DECEL=<percent>`` and ``NEXT``), Robot_Halt,
  Robot_Speed, Robot_GetVariable
  (``@CURRENT_POSITION``, ``@CURRENT_ANGLE``, ``@TYPE_NAME``: the model of the rig's DENSO arm),
  Robot_Release, Variable_GetValue / PutValue /
  Release (controller ``@VERSION``, ``@MODE`` and user variables ``I1``, ``F2``, ``D3``,
  ``S4``, ``P5`` …).
* Handles per connection (released when the connection closes, with the arm); the motor and
  the rig are shared by all connections, like one physical controller.
* A move needs TakeArm (else E_ACCESSDENIED 0x80070005: a stand-in, as the real controller's
  code for this could not be checked) and the motor on (else 0x81501003).
* Motion runs on the trapezoidal profile of :mod:`tmscal.motion` on the real-time clock
  (``motion_time_s`` overrides its duration), at once on the fast clock (the modelled
  duration is still recorded in ``last_motion_s``). Speed = ``SPEED`` option (percent,
  default 100) × ExtSpeed (percent) × ``max_linear_speed_mm_s``; acceleration = ACCEL /
  DECEL (percent) × ExtSpeed accel / decel (percent; default speed² / 100 as on the RC8) ×
  ``max_linear_accel_mm_s2``, the profile running at their harmonic mean (docs/devices.md).
  Every percentage must be finite and in [0.01, 100] (else E_INVALIDARG). Without
  ``mock.kinematics`` CurJnt returns zeros; with it, the rig's joints (docs/selfcal.md). A
  halted real-time motion stops on its path (the blocking move then answers E_FAIL).
* While a motion runs, any request on its connection, Robot_Halt included, gets E_BUSY_PROC
  (0x809100AA), as from DENSO's reference b-CAP server; Robot_Halt from any other connection
  stops the arm. With NEXT the move answers at once but the connection stays busy until the
  motion ends. A blocking ``@E`` move replies when the arm is still; ``@P`` / ``@0`` (pass)
  reply up to ``SETTLE_S`` earlier (fast clock: at once, the arm at rest by the next request).
  With a watchdog, a blocking move sends one S_EXECUTING packet per WDT period it lasts.
  Faults ``latched_error`` (TakeArm / Motor / Move refused until ClearError) and
  ``hold_move_at`` (a move that runs until halted); see ``docs/devices.md``.
* One reply per request, in one ``sendall``, with the request's serial; malformed requests
  get E_INVALIDPACKET, bad arguments E_INVALIDARG (NaN, ±inf and out-of-range numbers
  included), unknown handles E_HANDLE, anything the mock cannot handle E_FAIL; the socket is
  never closed mid-request except by the ``drop_at_request`` fault.

Poses: the rig's ``base_from_flange`` 4×4 mm ↔ P-type via ``tmscal.geometry``.
"""

from .args import PCT_MAX, PCT_MIN
from .controller import WDT_MAX_MS, WDT_MIN_MS
from .mock import DensoMock
from .state import BAD_CURPOS, DensoFaults

__all__ = ["DensoMock", "DensoFaults", "BAD_CURPOS", "PCT_MIN", "PCT_MAX", "WDT_MIN_MS",
           "WDT_MAX_MS"]
