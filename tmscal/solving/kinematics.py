"""The arm in the solve service (docs/kinematics.md, "Using it"): a session's recorded joints
and which arm it was recorded with; the robot poses a calibration applies to a session (an
identified arm recomputes them from the joints); an arm given as a model (a kinematics file)
made into the calibration's arm; and the coil placement against a session's truth, through
the flange command a calibration gives and, when the truth has an arm, the controller that
executes it.

Frames: A = base_from_flange as the controller reports it (its frame; for a mock or simulated
rig, the rig frame = mount · robot base), B = tracker_from_marker, C = tracker_from_probe,
X, Y, Z as everywhere; 4×4 mm; joints rad.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..calib import Calibration
from ..calib import diagnose as dg
from ..calib.kinematics.arms import ARMS, arm_by_name
from ..calib.kinematics.calibrated import ArmCalibration, controller_frame, spread_seeds
from ..calib.kinematics.ik import inverse
from ..calib.kinematics.model import Arm, base_from_flange, forward
from ..calib.metrics import placement_errors
from ..errors import CalibrationError, ConfigError, SessionError
from ..session import Session

__all__ = ["JOINTS_HINT", "ARM_DEFINITION_KEY", "recorded_arm", "recorded_definition",
           "choose_definition", "choose_arm", "session_joints", "usable_joints",
           "applied_arrays", "arm_forward", "session_frames", "given_arm", "truth_arm_of",
           "truth_controller", "coil_placement"]

#: what to do about a pose without joints
JOINTS_HINT = "record the session with a robot driver that reports joints (docs/kinematics.md)"


#: where a session header records the arm's definition (tmscal.formats.armdef)
ARM_DEFINITION_KEY = ("devices", "robot", "arm_definition")


def recorded_arm(session: Session) -> str | None:
    """The arm the session's robot driver reported (the header's ``devices.robot.arm``, a
    registry name), or None."""
    robot = (session.header.get("devices") or {}).get("robot")
    arm = robot.get("arm") if isinstance(robot, dict) else None
    return arm if isinstance(arm, str) and arm else None


def recorded_definition(session: Session) -> Any:
    """The arm definition the session header records (``devices.robot.arm_definition``, a
    :class:`tmscal.formats.armdef.ArmDefinition` rebuilt from its content, no file read),
    else the registry arm its driver reported (``devices.robot.arm``), else None.
    CalibrationError naming the session and the key for a record that is not valid."""
    from ..formats.armdef import ArmDefinition, arm_from_record

    robot = (session.header.get("devices") or {}).get("robot")
    rec = robot.get("arm_definition") if isinstance(robot, dict) else None
    if rec is not None:
        return arm_from_record(rec, f"{session.path or 'session'}: header key "
                               f"'{'.'.join(ARM_DEFINITION_KEY)}'")
    name = recorded_arm(session)
    if name is not None and name in ARMS:
        return ArmDefinition(arm=ARMS[name].arm, kind="registry", name=name)
    return None


def choose_definition(session: Session, arm: Any, urdf_base: str | None = None,
                      urdf_flange: str | None = None) -> tuple[Any, str]:
    """The nominal arm's definition (an ``ArmDefinition``) of a kinematic calibration and
    where it came from: ``arm`` (a registry name, a shipped arm file's name, or the path of a
    URDF or arm file; :func:`tmscal.formats.armdef.resolve_arm`; or an ``ArmDefinition``
    already resolved), else the one the session
    recorded. CalibrationError when ``arm`` is not the arm the session recorded (naming both
    and the header key; a file of as many joints as the registry arm its driver reported is
    taken: it refines the reported model), naming the known arms for an unknown name, or
    asking for ``arm`` when the session recorded none."""
    from ..formats.armdef import ArmDefinition, resolve_arm

    where = session.path or "session"
    recorded = recorded_definition(session)
    if arm is None:
        if recorded is None:
            name = recorded_arm(session)
            if name is not None:   # a model the registry does not know
                try:
                    arm_by_name(name, "the session header (devices.robot.arm)")
                except ConfigError as e:
                    raise CalibrationError(str(e)) from None
            raise CalibrationError(
                f"{where}: the session does not say which arm recorded it (its robot driver "
                f"reported no model): name it with arm= (one of {', '.join(ARMS)}, or a URDF "
                "or arm file)")
        key = "devices.robot.arm_definition" if recorded.kind != "registry" \
            else "devices.robot.arm"
        return recorded, f"the session header ({key})"
    try:
        given = arm if isinstance(arm, ArmDefinition) else \
            resolve_arm(arm, "arm=", urdf_base, urdf_flange)
    except ConfigError as e:
        raise CalibrationError(str(e)) from None
    if recorded is not None and recorded.kind == "registry" and given.kind != "registry" \
            and given.arm.n_joints == recorded.arm.n_joints:
        # the driver reported only the model: a file of it (its URDF, its arm file) refines it
        return given, f"arm= (the session's driver reported {recorded.name})"
    if recorded is not None and not given.same_as(recorded):
        key = "devices.robot.arm_definition" if recorded.kind != "registry" \
            else "devices.robot.arm"
        raise CalibrationError(
            f"{where}: the session was recorded with {recorded.describe()} (header key "
            f"'{key}'); arm= gives {given.describe()}: give the arm the session was recorded "
            "with, or none (the recorded one is used)")
    return given, "arm="


def choose_arm(session: Session, arm: Any, urdf_base: str | None = None,
               urdf_flange: str | None = None) -> tuple[Arm, str]:
    """The nominal arm (:class:`Arm`) of :func:`choose_definition` and where it came from."""
    d, source = choose_definition(session, arm, urdf_base, urdf_flange)
    return d.arm, source


def session_joints(session: Session, indices: list[int], purpose: str) -> np.ndarray:
    """The recorded joints (m, dof) rad of poses ``indices``, in that order. CalibrationError
    naming the first pose without joints (or with another number of them) and ``purpose``,
    what needs them."""
    try:
        return session.joints(indices, f"{purpose} needs the joints of every pose used: "
                              + JOINTS_HINT)
    except SessionError as e:
        raise CalibrationError(str(e)) from None


def usable_joints(session: Session, indices: list[int]) -> np.ndarray | None:
    """The joints of poses ``indices`` when every one recorded them (alike in number), else
    None."""
    try:
        return session_joints(session, indices, "")
    except CalibrationError:
        return None


def _check_dof(q: np.ndarray, arm: Arm, where: str) -> None:
    if q.shape[1] != arm.n_joints:
        raise CalibrationError(f"{where}: the session's poses have {q.shape[1]} joint angles; "
                               f"the {arm.name} arm has {arm.n_joints}")


def applied_arrays(session: Session, cal: Calibration, need_probe: bool
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[int],
                              np.ndarray | None]:
    """(A, B, C, indices, joints) of the usable poses of ``session`` as the calibration
    applies them: with an identified arm (``cal.arm``) A is recomputed from the recorded
    joints (``Calibration.robot_poses``) and ``joints`` are those; otherwise A as recorded
    and the joints when every pose has them. CalibrationError naming the first pose without
    joints when the arm needs them."""
    A, B, C, idx = session.arrays(need_probe=need_probe)
    if cal.arm is None or len(A) == 0:
        return A, B, C, idx, (usable_joints(session, idx) if len(A) else None)
    q = session_joints(session, idx, f"the calibration's identified {cal.arm.nominal.name} "
                       "arm (it recomputes the robot poses from the joints)")
    _check_dof(q, cal.arm.nominal, str(session.path or "session"))
    return cal.robot_poses(A, q), B, C, idx, q


def arm_forward(session: Session, cal: Calibration, A: np.ndarray, q: np.ndarray | None
                ) -> Callable[[np.ndarray], np.ndarray] | None:
    """joints (n, dof) rad → robot poses (n, 4, 4) mm in the frame of ``A`` (the poses as
    ``applied_arrays`` gives them): the calibration's identified arm, else the arm the
    session's driver reported when the recorded poses A are its nominal kinematics in one
    fixed frame; None without joints or such an arm (the arm hypothesis of the daily
    check's diagnosis then cannot be tested, docs/lab-day.md)."""
    if q is None or len(A) == 0:
        return None
    if cal.arm is not None:
        return cal.arm.robot_poses
    name = recorded_arm(session)
    if name is None or name not in ARMS:
        return None
    nominal = arm_by_name(name)
    if q.shape[1] != nominal.n_joints:
        return None
    try:
        M = controller_frame(nominal, A, q, str(session.path or "session"))
    except CalibrationError:
        return None
    return lambda qq: M @ base_from_flange(nominal, np.atleast_2d(qq))


def session_frames(session: Session, cal: Calibration) -> dg.Frames:
    """The session's usable poses as the calibration ``cal`` applies them (its arm, its
    distortion; ``calib.diagnose.frames``: the daily check's diagnosis and ``--update``,
    docs/lab-day.md), the probe where both the calibration and the session have it, with the
    joints and the arm's forward kinematics where the arm hypothesis can be tested
    (:func:`arm_forward`). CalibrationError as :func:`applied_arrays` raises it, or when no
    pose is usable."""
    with_probe = cal.Y is not None and "probe" in session.bodies
    A, B, C, idx, q = applied_arrays(session, cal, need_probe=with_probe)
    if len(A) == 0:
        raise CalibrationError(f"{session.path}: no usable poses in the session")
    fk = arm_forward(session, cal, A, q)
    return dg.frames(cal, A, B, C if with_probe else None, q if fk else None, fk, idx)


def given_arm(session: Session, model: Arm, source: str
              ) -> tuple[Session, ArmCalibration | None]:
    """An arm given as a model (e.g. a kinematics file of ``tmscal selfcal identify``): the
    session with the robot pose A of every usable pose recomputed from its joints, and the
    calibration's arm. When ``model`` names a registered arm whose nominal kinematics the
    recorded poses follow (in one fixed controller frame M), A = M · base_from_flange(model,
    q) and the arm is an :class:`ArmCalibration` (the nominal, ``model``, M, seeds;
    ``report`` {"source": ``source``}), so that the calibration commands the robot through
    it; otherwise A = base_from_flange(model, q), the robot's own base frame, and the arm is
    None (as :func:`tmscal.solving.solve.with_kinematics` computes them). CalibrationError
    naming the first usable pose without joints."""
    from dataclasses import replace

    use = [p for p in session.poses if p.skipped is None and p.A is not None]
    if not use:
        return session, None
    where = str(session.path or "session")
    q = session_joints(session, [p.index for p in use], f"kinematics=<an arm> ({source})")
    _check_dof(q, model, where)
    A_rec = np.stack([p.A for p in use])
    ac = None
    if model.name in ARMS:
        nominal = arm_by_name(model.name)
        try:
            M = controller_frame(nominal, A_rec, q, where)
        except CalibrationError:
            M = None
        if M is not None and (nominal.n_joints, nominal.convention) == \
                (model.n_joints, model.convention):
            ac = ArmCalibration(nominal=nominal, arm=model, controller_frame=M,
                                seeds=spread_seeds(q), report={"source": source})
    A_new = ac.robot_poses(q) if ac is not None else base_from_flange(model, q)
    new = dict(zip((p.index for p in use), A_new, strict=True))
    poses = [replace(p, A=new[p.index]) if p.index in new else p for p in session.poses]
    return replace(session, poses=poses), ac


def truth_arm_of(session: Session) -> dict[str, Any] | None:
    """The arm of a session's truth (``Session.truth_arm``: {"name", "errors", "nominal",
    "true": Arm, "mount": 4×4 mm}), or None when the truth has none."""
    return getattr(session, "truth_arm", None)


def truth_controller(truth_arm: dict[str, Any], seeds: np.ndarray | None
                     ) -> Callable[[np.ndarray], np.ndarray]:
    """The controller of a truth's arm, as a function of commanded flange poses A_cmd (n, 4,
    4) mm in its frame (the rig frame): it solves its NOMINAL kinematics for the joints
    (inverse kinematics from ``seeds[i]``, the joints the arm had at target i, rad; without
    seeds from the registry's home configuration), and the flange really goes where the TRUE
    arm puts those joints: mount · forward(true, q). CalibrationError naming the target the
    nominal arm cannot reach."""
    nominal: Arm = truth_arm["nominal"]
    true: Arm = truth_arm["true"]
    mount = np.asarray(truth_arm["mount"], dtype=float)
    to_base = np.linalg.inv(mount @ nominal.base)
    spec = ARMS.get(str(truth_arm.get("name")))
    home = [np.asarray(spec.home_q, dtype=float)] if spec is not None else []

    def reached(A_cmd: np.ndarray) -> np.ndarray:
        out = np.empty_like(np.asarray(A_cmd, dtype=float))
        for i, T in enumerate(A_cmd):
            first = [] if seeds is None else [np.asarray(seeds[i], dtype=float)]
            q = inverse(nominal, to_base @ T, first + home)
            if q is None:
                raise CalibrationError(
                    f"target {i}: the truth's {nominal.name} controller cannot reach the "
                    f"commanded flange pose {np.round(T[:3, 3], 1).tolist()} mm")
            out[i] = mount @ forward(true, q)
        return out
    return reached


def coil_placement(cal: Calibration, C: np.ndarray, truth: dict[str, np.ndarray],
                   truth_arm: dict[str, Any] | None = None,
                   joints: np.ndarray | None = None) -> np.ndarray:
    """The coil placement error (mm) per target C_i (n, 4, 4), against the truth's Y and Z:
    the robot is commanded ``cal.flange_command(C_i)`` (the placement rule, and with an
    identified arm the pose its controller must be told; seeded with ``joints[i]``, the
    joints the arm had there); the flange reaches that command exactly, or, when the truth
    has an arm (``truth_arm``), where :func:`truth_controller` takes it
    (``calib.metrics.placement_errors``)."""
    C = np.asarray(C, dtype=float).reshape(-1, 4, 4)
    if joints is not None and len(joints) != len(C):
        joints = None
    if cal.arm is None or joints is None:
        A_cmd = cal.flange_command(C)
    else:
        A_cmd = np.concatenate([cal.flange_command(C[i:i + 1], seeds=joints[i])
                                for i in range(len(C))])
    reached = None if not truth_arm else truth_controller(truth_arm, joints)
    return placement_errors(A_cmd, C, truth["Y"], truth["Z"], reached)
