"""``tmscal solve SESSION --calib CALIB``: the daily check of a stored calibration on a new
session, no fitting (:mod:`tmscal.check`), and with ``--tolerance-mm`` /
``--tolerance-deg`` its verdict: a PASS or FAIL line, in the JSON as "verdict", and the exit
status (0 PASS, ``EXIT_CHECK_FAILED`` FAIL) so that a lab can script it before each TMS
session. The options are the ``solve`` command's (:mod:`tmscal.cli.solve`)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click

from .app import (
    EXIT_CHECK_FAILED,
    FORCE_HELP,
    INPUT_FILE,
    STRICT_HELP,
    Finite,
    check_outputs,
    handle_errors,
    main,
    print_json,
    read_session_file,
    write_atomic,
)

__all__ = ["check", "check_stored", "calibration_origin", "CHECK_OPTIONS"]

#: the daily check's options, shared by ``tmscal check`` and ``tmscal solve --calib``
CHECK_OPTIONS = [
    click.option("--tolerance-mm", type=Finite(0, lo_open=True), default=None, metavar="MM",
                 help="With --calib: decide. PASS when the total hold-out error e_t (mm, the "
                      "last row) is at most MM, else FAIL; one line, in the JSON as "
                      "'verdict', exit status 0 or 3 (docs/exports.md, \"The daily check\")."),
    click.option("--tolerance-deg", type=Finite(0, lo_open=True), default=None, metavar="DEG",
                 help="With --calib: likewise for the total rotation error θ_t (degrees)."),
    click.option("--update", "update", multiple=True, metavar="z|x|y|coil",
                 type=click.Choice(["z", "x", "y", "coil"]),
                 help="With --calib: re-register only this transform from the session's "
                      "poses (z: the tracker moved, x: the marker moved on the coil, y: the "
                      "coil's centre, coil: the coil re-seated, X and Y together), everything "
                      "else and any identified arm kept; repeatable (z with x or y). Refused, "
                      "nothing written, when the result still does not explain the session (a "
                      "second change). -o writes the updated calibration, its parent named by "
                      "SHA-256 (docs/lab-day.md)."),
]


def check_options(fn: Any) -> Any:
    """Decorate a command with :data:`CHECK_OPTIONS`."""
    for opt in reversed(CHECK_OPTIONS):
        fn = opt(fn)
    return fn


@main.command()
@click.argument("session_file", type=INPUT_FILE)
@click.option("--calib", "calib_file", type=INPUT_FILE, required=True, metavar="CALIB",
              help="The stored calibration to check (a file of tmscal solve -o, or a json "
                   "export): every pose held out, the errors beside the stored ones, coil "
                   "placement against the truth when the session has one, the calibration's "
                   "provenance and what moved since. No fitting.")
@check_options
@click.option("--kinematics", "kin_file", type=INPUT_FILE, default=None, metavar="KIN",
              help="Recompute every robot pose A from the recorded joints with the arm's "
                   "calibrated kinematics (a file of tmscal selfcal identify -o) before the "
                   "check (docs/selfcal.md).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="With --update: write the updated calibration YAML here.")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@click.option("--strict", is_flag=True, help=STRICT_HELP)
@handle_errors
def check(session_file: Path, calib_file: Path, tolerance_mm: float | None,
          tolerance_deg: float | None, update: tuple[str, ...], kin_file: Path | None,
          as_json: bool, output: Path | None, force: bool, strict: bool) -> None:
    """The daily check: a stored calibration on a new session, no fitting (docs/lab-day.md).
    Says what moved since the calibration was solved (the tracker, the coil re-seated, the
    marker, the coil's centre, the arm); with --tolerance-mm/--tolerance-deg a PASS or FAIL
    line and exit status 0 or 3; with --update, re-registers only the named transforms.
    ``tmscal solve SESSION --calib CALIB`` is the same command."""
    check_stored(session_file, calib_file, as_json, strict, output=output, plot=None,
                 fitting=False, kin_file=kin_file, tolerance_mm=tolerance_mm,
                 tolerance_deg=tolerance_deg, update=list(update), force=force)


def _with_kinematics(session: Any, kin_file: Path | None) -> Any:
    """The session with A recomputed from its joints by the arm model of ``kin_file``
    (``solving.solve.with_kinematics``), or as it is without one."""
    if kin_file is None:
        return session
    from ..formats.kinfile import load_arm
    from ..solving.solve import with_kinematics
    return with_kinematics(session, load_arm(kin_file), str(kin_file))


def check_stored(session_file: Path, calib_file: Path, as_json: bool, strict: bool,
                 output: Path | None, plot: Path | None, fitting: bool,
                 kin_file: Path | None = None, tolerance_mm: float | None = None,
                 tolerance_deg: float | None = None, update: list[str] | None = None,
                 force: bool = False) -> None:
    """``solve SESSION --calib CALIB``: the stored calibration on the session, no fitting;
    exits ``EXIT_CHECK_FAILED`` after printing when the verdict is FAIL. With ``update``
    (``--update`` names) the partial re-registration instead (:func:`_update`)."""
    from ..check import check_calibration, format_check
    from ..formats.calibfile import read_calibration
    from ..session import sha256_of

    if update:
        for opt, given in (("--plot", plot is not None),
                           ("--tolerance-mm/--tolerance-deg",
                            tolerance_mm is not None or tolerance_deg is not None),
                           ("--kinematics", kin_file is not None)):
            if given:
                raise click.BadParameter("not with --update (it re-registers the named "
                                         "transforms and checks the result itself)",
                                         param_hint=opt)
        _update(session_file, calib_file, update, as_json, strict, output, fitting, force)
        return
    for opt, given in (("--output", output is not None), ("--plot", plot is not None),
                       ("--method/--option/--train/--in-sample/--orthonormal/--handheld-pose",
                        fitting)):
        if given:
            raise click.BadParameter(f"{opt} solves or writes a calibration; --calib only "
                                     "checks a stored one (leave it out, or re-register with "
                                     "--update)", param_hint="--calib")
    cf = read_calibration(calib_file)
    if kin_file is not None and cf.calibration.arm is not None:
        raise click.BadParameter(f"{calib_file} carries its own identified arm, with which "
                                 "the robot poses are recomputed; leave --kinematics out",
                                 param_hint="--kinematics")
    session = _with_kinematics(read_session_file(session_file, strict), kin_file)
    res = check_calibration(session, cf, sha256_of(session_file), tolerance_mm=tolerance_mm,
                            tolerance_deg=tolerance_deg)
    if as_json:
        print_json(res)
    else:
        click.echo(format_check(res))
    if res["verdict"] is not None and res["verdict"]["result"] == "FAIL":
        sys.exit(EXIT_CHECK_FAILED)


def _update(session_file: Path, calib_file: Path, names: list[str], as_json: bool,
            strict: bool, output: Path | None, fitting: bool, force: bool) -> None:
    """``solve SESSION --calib CALIB --update NAME…``: re-register the named transforms
    (``check.update_calibration``); ``-o`` writes the updated calibration with its
    lineage. A refused update prints the refusal and the diagnosis, writes nothing and exits
    ``EXIT_CHECK_FAILED``."""
    from ..calib.diagnose import UpdateRefused
    from ..check import format_diagnosis, format_update, next_command, update_calibration
    from ..formats.calibfile import provenance, read_calibration, updated_calibration_yaml
    from ..session import plain, sha256_of

    if fitting:
        raise click.BadParameter("--method/--option/--train/--in-sample/--orthonormal/"
                                 "--handheld-pose solve anew; --update keeps the stored "
                                 "calibration's method and re-registers only the named "
                                 "transforms (leave them out)", param_hint="--update")
    check_outputs({"--output": output}, [session_file, calib_file], force)
    cf = read_calibration(calib_file)
    session = read_session_file(session_file, strict)
    try:
        res = update_calibration(session, cf, names)
    except UpdateRefused as e:
        d = e.diagnosis.to_json() if e.diagnosis is not None else None
        if d is not None:
            d["next_command"] = next_command(d["changed"], str(session_file), str(calib_file))
            d["noise_model"] = getattr(e, "noise_source", None)
        if as_json:
            print_json({"refused": str(e), "diagnosis": d})
        else:
            click.echo(f"REFUSED: {e}")
            if d is not None:
                click.echo("\n".join(format_diagnosis(d)))
        sys.exit(EXIT_CHECK_FAILED)
    if output is not None:
        write_atomic(output, updated_calibration_yaml(
            cf, sha256_of(calib_file), res["calibration"], plain(res["update"]),
            str(session_file), sha256_of(session_file), res["n_poses"], res["errors"],
            provenance(session.header), res["noise_model"]), force)
    if as_json:
        print_json({"update": res["update"], "errors": res["errors"], "truth": res["truth"],
                    "output": None if output is None else str(output)})
    else:
        click.echo(format_update(res, str(calib_file), None if output is None
                                 else str(output)))


def calibration_origin(calib_file: Path | None) -> Any:
    """The P0 where the calibration ``calib_file`` was made (``CalibrationFile.p0``), or None
    without a file; a calibration that records none is a BadParameter naming it."""
    if calib_file is None:
        return None
    from ..formats.calibfile import read_calibration
    origin = read_calibration(calib_file).p0
    if origin is None:
        raise click.BadParameter(f"{calib_file} records no P0 (it was written before tmscal "
                                 "stored where a calibration was made): solve its session "
                                 "again with -o", param_hint="--calib")
    return origin
