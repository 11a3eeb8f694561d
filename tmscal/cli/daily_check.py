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

from .app import EXIT_CHECK_FAILED, print_json, read_session_file

__all__ = ["check_stored"]


def _with_kinematics(session: Any, kin_file: Path | None) -> Any:
    """The session with A recomputed from its joints by the arm model of ``kin_file``
    (``solving.solve.with_kinematics``), or as it is without one."""
    if kin_file is None:
        return session
    from ..exports.kinfile import load_arm
    from ..solving.solve import with_kinematics
    return with_kinematics(session, load_arm(kin_file), str(kin_file))


def check_stored(session_file: Path, calib_file: Path, as_json: bool, strict: bool,
                 output: Path | None, plot: Path | None, fitting: bool,
                 kin_file: Path | None = None, tolerance_mm: float | None = None,
                 tolerance_deg: float | None = None) -> None:
    """``solve SESSION --calib CALIB``: the stored calibration on the session, no fitting;
    exits ``EXIT_CHECK_FAILED`` after printing when the verdict is FAIL."""
    from ..exports.calibfile import read_calibration
    from ..exports.check import check_calibration, format_check
    from ..session import sha256_of

    for opt, given in (("--output", output is not None), ("--plot", plot is not None),
                       ("--method/--option/--train/--in-sample/--orthonormal/--handheld-pose",
                        fitting)):
        if given:
            raise click.BadParameter(f"{opt} solves or writes a calibration; --calib only "
                                     "checks a stored one (leave it out)", param_hint="--calib")
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
