"""``tmscal robot``: the robot's identity and flange pose, optionally a jog; and the one-line
pose text (position mm, roll/pitch/yaw deg) ``acquire --dry-run`` prints too."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
import numpy as np

from ..escape import value_text
from .app import INPUT_FILE, ROBOT_HOST_HELP, Finite, handle_errors, main, old_spelling
from .check import calibration_origin


def _matrix_text(T: np.ndarray) -> str:
    from ..report.text import format_matrix
    return format_matrix(T)


#: how the roll/pitch/yaw angles printed by pose_line compose (DENSO's P-type; --move-to)
RPY_CONVENTION = "R = Rz(yaw)·Ry(pitch)·Rx(roll), fixed base axes, as DENSO's P-type"


def pose_line(T: np.ndarray) -> str:
    """Position (mm) and roll/pitch/yaw (deg, ``RPY_CONVENTION``) of a 4×4 pose in mm; the
    labels never reuse a UR pendant's rx ry rz, which there mean a rotation vector."""
    from ..geometry import denso_p_from_matrix
    p = denso_p_from_matrix(T)
    return (f"x {p[0]:9.2f}  y {p[1]:9.2f}  z {p[2]:9.2f} mm   "
            f"roll/pitch/yaw {p[3]:.3f} {p[4]:.3f} {p[5]:.3f} deg")


def _pendant_line(T: np.ndarray, rb: Any) -> str | None:
    """For a UR: the TCP pose as its teach pendant shows it (X Y Z mm, RX RY RZ the rotation
    vector in rad; Universal Robots, PolyScope manual, Move screen), else None."""
    from ..geometry import rotvec_pose_from_matrix
    tcp = getattr(rb, "flange_from_tcp", None)
    if tcp is None:
        return None
    v = rotvec_pose_from_matrix(T @ np.asarray(tcp, dtype=float))
    return (f"UR pendant (TCP): X {v[0] * 1000:.2f}  Y {v[1] * 1000:.2f}  Z {v[2] * 1000:.2f} "
            f"mm   RX {v[3]:.4f}  RY {v[4]:.4f}  RZ {v[5]:.4f} rad (rotation vector)")


def _echo_pose(label: str, T: np.ndarray, rb: Any = None) -> None:
    """``label`` and the pose on one line, the angle convention (and, for a UR, the pendant's
    view) indented below."""
    click.echo(f"{label}: {pose_line(T)}")
    click.echo(f"  angles: {RPY_CONVENTION}")
    pendant = _pendant_line(T, rb) if rb is not None else None
    if pendant:
        click.echo("  " + pendant)


@main.command()
@click.argument("config", type=INPUT_FILE)
@click.option("--robot-host", default=None, help=ROBOT_HOST_HELP)
@click.option("--host", "old_host", default=None, hidden=True)
@click.option("--move-to", "move_to", default=None, metavar="X,Y,Z,ROLL,PITCH,YAW",
              help="Jog the flange to this pose after a confirmation: x, y, z in mm and "
                   "roll, pitch, yaw in degrees with R = Rz(yaw)·Ry(pitch)·Rx(roll) about the "
                   "fixed base axes (DENSO's P-type; NOT a UR pendant's rotation vector), in "
                   "the robot base frame. The config's safety envelope applies around the "
                   "current pose (with --calib: around the calibration's P0). 'p0' with "
                   "--calib: back to the P0 where the calibration was made, always allowed "
                   "inside the workspace box at the speed caps.")
@click.option("--calib", "calib_file", type=INPUT_FILE, default=None, metavar="CALIB",
              help="The calibration whose P0 --move-to p0 goes back to (docs/safety.md).")
@click.option("--speed", type=Finite(0, lo_open=True), default=None,
              help="Jog speed, mm/s (capped by safety.max_speed_mm_s).")
@click.option("--yes", is_flag=True, help="Do not ask for confirmation.")
@handle_errors
def robot(config: Path, robot_host: str | None, old_host: str | None, move_to: str | None,
          calib_file: Path | None, speed: float | None, yes: bool) -> None:
    """Connect to the robot, report its identity and flange pose; optionally jog."""
    from ..acquisition.devices import envelope_for, make_robot
    from ..config import load_config
    from ..geometry import matrix_from_denso_p
    from ..safety.origin import return_envelope

    host = old_spelling(robot_host, old_host, "--robot-host", "--host")
    target = None
    origin = calibration_origin(calib_file)
    back = move_to is not None and move_to.strip().lower() == "p0"
    if back:
        if origin is None:
            raise click.BadParameter("'p0' is the calibration's P0: give --calib CALIB",
                                     param_hint="--move-to")
        target = np.array(origin.pose, dtype=float)
    elif move_to is not None:  # parsed before anything connects
        try:
            vals = [float(v) for v in move_to.split(",")]
            if len(vals) != 6 or not np.isfinite(vals).all():
                raise ValueError
        except ValueError:
            raise click.BadParameter(f"{move_to!r}: expected 6 finite numbers "
                                     "X,Y,Z,ROLL,PITCH,YAW (mm, deg)",
                                     param_hint="--move-to") from None
        target = matrix_from_denso_p(vals)
    cfg = load_config(config, check_files=False)  # the robot needs no tracker files
    with make_robot(cfg, envelope_for(cfg, None), host) as rb:
        click.echo("robot: " + ", ".join(f"{k} {value_text(v)}"
                                         for k, v in rb.identity().items() if v))
        here = rb.flange_pose()
        _echo_pose("flange (base ← flange)", here, rb)
        click.echo(_matrix_text(here))
        if target is None:
            return
        if origin is None:
            rb.envelope = envelope_for(cfg, here)
        elif back:  # the way back: the box and the caps only
            rb.envelope = return_envelope(envelope_for(cfg, origin.pose), origin.pose, here)
        else:
            rb.envelope = envelope_for(cfg, origin.pose)
        rb.envelope.check_pose(target, "--move-to target")
        v = speed if speed is not None else rb.speed_mm_s
        _echo_pose("target", target, rb)
        if not yes and not click.confirm(f"move the flange to the target at {v} mm/s?",
                                         default=False):
            click.echo("not moved")
            return
        rb.move_to(target, v)
        _echo_pose("arrived", rb.flange_pose(), rb)
