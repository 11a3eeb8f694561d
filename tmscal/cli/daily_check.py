"""``tmscal solve SESSION --calib CALIB``: the daily check of a stored calibration on a new
session, no fitting (:mod:`tmscal.exports.check`), and with ``--tolerance-mm`` /
``--tolerance-deg`` its verdict: a PASS or FAIL line, in the JSON as "verdict", and the exit
status (0 PASS, ``EXIT_CHECK_FAILED`` FAIL) so that a lab can script it before each TMS
session. The options are the ``solve`` command's (:mod:`tmscal.cli.offline`)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click

from .app import EXIT_CHECK_FAILED, check_outputs, print_json, read_session_file, write_atomic

__all__ = ["check_stored", "calibration_origin"]


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
    from ..exports.check import check_calibration, format_check
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
    (``exports.check.update_calibration``); ``-o`` writes the updated calibration with its
    lineage. A refused update prints the refusal and the diagnosis, writes nothing and exits
    ``EXIT_CHECK_FAILED``."""
    from ..calib.diagnose import UpdateRefused
    from ..exports.check import format_diagnosis, format_update, next_command, update_calibration
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
