"""``tmscal import``: an external measurement campaign (a laser tracker's 6D probe or three
reflectors, with the robot's joints) as a session (docs/kinematics.md, "Laser trackers and 6D
probes"). Thin: the reader is :mod:`tmscal.formats.campaign`."""

from __future__ import annotations

from pathlib import Path

import click

from .app import FORCE_HELP, INPUT_FILE, check_outputs, handle_errors, main
from .selfcal import ArmName


def _names(value: str | None) -> tuple[str, ...]:
    return tuple(v.strip() for v in value.split(",") if v.strip()) if value else ()


@main.command("import")
@click.argument("csv_file", metavar="CSV", type=INPUT_FILE)
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Session file to write (JSON Lines): one pose per row, marker only.")
@click.option("--arm", type=ArmName(), required=True,
              help="The arm that moved (a registered name, docs/kinematics.md): the robot "
                   "poses A are its nominal forward kinematics of the joints, what its "
                   "controller would report.")
@click.option("--joints", required=True, metavar="COL,…",
              help="The joint columns, in the chain's order.")
@click.option("--joint-unit", type=click.Choice(["rad", "deg"]), default="rad",
              show_default=True, help="Unit of the joint columns.")
@click.option("--position", default=None, metavar="X,Y,Z",
              help="A 6D probe's position columns (with --rotation).")
@click.option("--rotation", default=None, metavar="COL,…",
              help="A 6D probe's orientation columns: 3 (Euler angles or a rotation vector) "
                   "or 4 (a quaternion), as --rotation-kind says.")
@click.option("--rotation-kind", default="euler:XYZ", show_default=True,
              metavar="euler:SEQ|quat:xyzw|quat:wxyz|rotvec",
              help="How --rotation is written: Euler angles of axes SEQ (upper case "
                   "intrinsic, lower case extrinsic, scipy's convention; Leica's T-Mac "
                   "exports intrinsic XYZ), a unit quaternion (scalar last or first), or a "
                   "rotation vector.")
@click.option("--angle-unit", type=click.Choice(["deg", "rad"]), default="deg",
              show_default=True, help="Unit of Euler angles and rotation vectors.")
@click.option("--points", default=None, metavar="P1X,P1Y,P1Z,P2X,…,P3Z",
              help="Instead of a 6D pose: three reflectors on the flange (9 columns); the "
                   "frame has its origin at p1, x towards p2, z normal to the three.")
@click.option("--length-unit", type=click.Choice(["mm", "m"]), default="mm",
              show_default=True, help="Unit of the position and point columns.")
@click.option("--delimiter", default=None, metavar="CHAR",
              help="Field delimiter (default: guessed from the header: ';', ',' or a tab).")
@click.option("--decimal", type=click.Choice([".", ","]), default=".", show_default=True,
              help="Decimal mark of the numbers (',' for spreadsheets that write 0,5; then "
                   "the fields are separated by ';').")
@click.option("--instrument", default="laser tracker", show_default=True,
              help="What measured the poses, as the session header records it.")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@handle_errors
def import_csv(csv_file: Path, output: Path, arm: str, joints: str, joint_unit: str,
               position: str | None, rotation: str | None, rotation_kind: str,
               angle_unit: str, points: str | None, length_unit: str, delimiter: str | None,
               decimal: str, instrument: str, force: bool) -> None:
    """Import a measurement campaign CSV (one row per pose: the robot's joints and the pose
    of a target on the flange that an external instrument measured — a laser tracker's 6D
    probe, or three reflectors) as a marker-only session: B the measured target (tracker ←
    target, mm), A the arm's nominal forward kinematics of the joints (base ← flange, mm).
    Then `tmscal solve SESSION --method ml --kinematics estimate` calibrates the arm with
    the hand/eye (X: flange ← target) and robot/world (Z) transforms. Example, the T-Mac
    export of a UR10 (docs/kinematics.md):

        tmscal import poses.csv -o s.jsonl --arm ur10 --delimiter ';' --decimal ,
        --joints shoulder_pan_joint,shoulder_lift_joint,elbow_joint,wrist_1_joint,
        wrist_2_joint,wrist_3_joint --position measurement_x,measurement_y,measurement_z
        --rotation measurement_rx,measurement_ry,measurement_rz --rotation-kind euler:XYZ
    """
    from ..calib.kinematics import arm_by_name
    from ..formats.campaign import (
        Columns,
        campaign_header,
        campaign_records,
        read_campaign,
    )
    from ..session import write_session

    check_outputs({"--output": output}, [csv_file], force)
    cols = Columns(joints=_names(joints), position=_names(position),
                   rotation=_names(rotation), rotation_kind=rotation_kind,
                   points=_names(points), joint_unit=joint_unit, length_unit=length_unit,
                   angle_unit=angle_unit)
    model = arm_by_name(arm, "--arm")
    c = read_campaign(csv_file, cols, delimiter, decimal)
    recs = campaign_records(c, model)
    header = campaign_header(c, model, cols, instrument)
    write_session(output, header, recs, overwrite=force)
    click.echo(f"{csv_file}: {len(recs)} poses (lines {c.lines[0]}–{c.lines[-1]}) of arm "
               f"{model.name}, measured by {instrument}; wrote {output}")
    click.echo(f"next: tmscal solve {output} --method ml --kinematics estimate "
               "(--train N to hold out the rest)")
