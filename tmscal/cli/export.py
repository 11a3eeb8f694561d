"""``tmscal export``: a stored calibration in the formats the lab's other software reads (3D
Slicer, PLUS, ROS easy_handeye, InVesalius, JSON; docs/exports.md)."""

from __future__ import annotations

from pathlib import Path

import click

from ..exports import FORMATS
from .app import FORCE_HELP, INPUT_FILE, check_outputs, handle_errors, main, write_atomic

_FORMAT_HELP = "; ".join(f"{k}: {v.help}" for k, v in FORMATS.items())


@main.command()
@click.argument("calib_file", type=INPUT_FILE, metavar="CALIB")
@click.option("--format", "fmt", required=True,
              type=click.Choice(list(FORMATS)),
              help=_FORMAT_HELP + ".")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="File to write (e.g. Z.tfm, plus.xml, handeye.yaml, robot.rbtf, calib.json).")
@click.option("--easy-handeye2", "handeye2", is_flag=True,
              help="easy-handeye: write easy_handeye2's (ROS 2) layout: transform.translation /"
                   " transform.rotation, calibration_type eye_on_base.")
@click.option("--frame", "frames", multiple=True, metavar="KEY=NAME",
              help="easy-handeye: a tf frame name (repeatable): robot_base_frame, "
                   "robot_effector_frame, tracking_base_frame or tracking_marker_frame "
                   "(defaults base_link, tool0, tracker, coil_marker).")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@handle_errors
def export(calib_file: Path, fmt: str, output: Path, handeye2: bool, frames: tuple[str, ...],
           force: bool) -> None:
    """Write the calibration CALIB (a file of tmscal solve -o, or a json export) as FORMAT.
    Each format's frames, units and conventions, and how to load it in its consumer, are in
    docs/exports.md; every format that allows comments names them in the file."""
    from ..exports import render
    from ..exports.easy_handeye import FRAMES
    from ..formats.calibfile import read_calibration

    if fmt != "easy-handeye" and (handeye2 or frames):
        raise click.BadParameter("only for --format easy-handeye",
                                 param_hint="--easy-handeye2/--frame")
    names: dict[str, str] = {}
    for f in frames:
        key, sep, val = f.partition("=")
        if not sep or key not in FRAMES or not val.strip() or " " in val.strip():
            raise click.BadParameter(f"{f!r}: expected KEY=NAME with KEY one of "
                                     f"{', '.join(FRAMES)}", param_hint="--frame")
        names[key] = val.strip()
    check_outputs({"--output": output}, [calib_file], force)
    cf = read_calibration(calib_file)
    opts = {"version": 2 if handeye2 else 1, "frames": names} if fmt == "easy-handeye" else {}
    write_atomic(output, render(fmt, cf, **opts), force)
    click.echo(f"wrote {output} ({fmt}{' 2' if handeye2 else ''}) from {calib_file}")
    for note in _notes(fmt, cf, output.suffix.lower()):
        click.echo(f"note: {note}")


def _notes(fmt: str, cf: object, out_suffix: str) -> list[str]:
    """What the user must know about what the format leaves out."""
    from ..formats.calibfile import CalibrationFile

    assert isinstance(cf, CalibrationFile)
    cal = cf.calibration
    out = []
    if cal.distortion and fmt != "json":
        out.append("the calibration found a tracker distortion; this format holds the rigid "
                   "X, Y, Z, as every export and tmscal stream, and does not correct it (the "
                   "json export records it; tmscal stream's CoilToRobotBase applies it)")
    if cal.arm is not None and fmt != "json":
        out.append(f"the calibration carries an identified {cal.arm.nominal.name} arm "
                   f"(docs/kinematics.md); {fmt} has no place for it, and X, Y, Z hold with "
                   "that arm's robot poses, not the controller's nominal ones: command the "
                   "robot through tmscal (stream's CoilToRobotBase) or read the json export")
    if fmt == "invesalius":
        from ..exports.invesalius import tcp_offset_mm
        x, y, z = tcp_offset_mm(cf)
        out.append(f"set the robot TCP offset to ({x:.3f}, {y:.3f}, {z:.3f}) mm, no rotation "
                   "(the marker's origin in the flange frame); the file has no slot for Y "
                   "nor for the coil on the marker (X⁻¹·Y): register the coil in InVesalius "
                   "as usual (docs/exports.md)")
    if fmt == "itk" and out_suffix not in (".tfm", ".txt"):
        out.append("ITK readers (3D Slicer, SimpleITK) pick the file type by its suffix: name "
                   "the file *.tfm")
    if fmt == "plus":
        from ..exports.plus import recorded_tracker, rom_files

        roms = rom_files(cf)
        if roms is None:
            out.append(f"the session's tracker (driver {recorded_tracker(cf)[0]!r}) is not an "
                       "NDI: the PLUS device set carries no ROM files; set its device type and "
                       "tool sources (the CHECK placeholders)")
        elif not roms:
            out.append("the calibration file does not record the tracker's tools (a simulated "
                       "session?): fill in the CHECK placeholders")
    return out
