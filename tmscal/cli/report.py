"""``tmscal report``: one self-contained HTML page of a session and its calibration, for a lab
notebook (the page is built by :mod:`tmscal.report.html`; docs/report.md)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from .app import (
    FORCE_HELP,
    INPUT_FILE,
    STRICT_HELP,
    Finite,
    check_outputs,
    handle_errors,
    main,
    read_session_file,
    write_atomic,
)
from .solve import MethodChoice


@main.command()
@click.argument("session_file", type=INPUT_FILE)
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="The HTML file to write (one file: figures embedded, no external links).")
@click.option("--calib", "calib_file", type=INPUT_FILE, default=None,
              help="Report this stored calibration (`tmscal solve -o` YAML or `tmscal export "
                   "--format json`) evaluated on the session, instead of solving the session.")
@click.option("--method", type=MethodChoice(), default="qr36", show_default=True,
              help="Without --calib: the method the session is solved with (see tmscal "
                   "solve --help). Methods without their own uncertainty get ml's beside it.")
@click.option("--folds", type=click.IntRange(2, 100), default=5, show_default=True,
              help="Without --calib: k-fold cross-validation of the held-out errors, as "
                   "tmscal solve.")
@click.option("--tolerance-mm", type=Finite(0, lo_open=True), default=None, metavar="MM",
              help="The verdict at the top of the page: PASS when the total held-out error "
                   "e_t (mm) is at most MM, else FAIL (the daily check's rule, tmscal solve "
                   "--calib; docs/first-day.md says how to choose it). The exit status stays "
                   "0: tmscal solve --calib --tolerance-mm is the scripted check.")
@click.option("--tolerance-deg", type=Finite(0, lo_open=True), default=None, metavar="DEG",
              help="Likewise for the total rotation error θ_t (degrees).")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@click.option("--strict", is_flag=True, help=STRICT_HELP)
@handle_errors
def report(session_file: Path, output: Path, calib_file: Path | None, method: str, folds: int,
           tolerance_mm: float | None, tolerance_deg: float | None, force: bool,
           strict: bool) -> None:
    """Write an HTML report of a session for the lab notebook. It opens with a verdict (the
    held-out errors against --tolerance-mm/--tolerance-deg, the predicted coil-placement
    error, whether an adaptive run recorded the session, the calibration's arm), then: the
    rig and its devices, the
    plan and its spread, the sample spreads and skipped poses, the calibration with its
    uncertainty, the held-out errors, the convergence curve (error against the number of
    poses) and the residuals by pose with the outlier poses named (docs/report.md).

    The page is self-contained (figures as embedded PNG, no scripts, no external links), so
    it can be attached, mailed or printed as it is. Needs matplotlib (extra 'plot')."""
    from tqdm import tqdm

    from ..check import verdict
    from ..errors import MissingExtraError
    from ..formats.calibfile import read_calibration
    from ..report.html import html_report
    from ..session import sha256_of

    inputs = [session_file] + ([calib_file] if calib_file is not None else [])
    check_outputs({"--output": output}, inputs, force)
    session = read_session_file(session_file, strict)
    calib = read_calibration(calib_file) if calib_file is not None else None
    with tqdm(desc="report", unit="solve", disable=None, file=sys.stderr,
              leave=False) as bar:
        def stage(name: str) -> None:
            bar.set_description(f"report: {name}")

        try:
            page = html_report(session, sha256_of(session_file), method=method.lower(),
                               calib=calib, folds=folds, progress=stage, solves=bar.update,
                               judge=lambda e: verdict(e, tolerance_mm, tolerance_deg))
        except ImportError as e:
            raise MissingExtraError("tmscal report", "plot", str(e)) from None
    write_atomic(output, page, force)
    click.echo(f"wrote {output} ({len(page.encode()) / 1e6:.1f} MB)")
