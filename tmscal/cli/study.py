"""``tmscal study``: the convergence study of a session (no devices)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from .app import (
    FORCE_HELP,
    INPUT_FILE,
    STRICT_HELP,
    check_outputs,
    handle_errors,
    main,
    output_files,
    print_json,
    read_session_file,
    run_plot,
)


@main.command()
@click.argument("session_file", type=INPUT_FILE)
@click.option("--methods", default="qr24,qr36", show_default=True,
              help="Comma-separated methods to compare.")
@click.option("--n-max", type=click.IntRange(5), default=250, show_default=True,
              help="Largest training set; poses from n-max on are the test set.")
@click.option("--orthonormal", is_flag=True, help="Apply orthonormal matrices.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the error against the number of poses as a PNG (as Figure 3 of "
                   "Wang et al. 2018).")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@click.option("--strict", is_flag=True, help=STRICT_HELP)
@handle_errors
def study(session_file: Path, methods: str, n_max: int, orthonormal: bool, as_json: bool,
          plot: Path | None, force: bool, strict: bool) -> None:
    """Convergence study of a session: errors against the number of poses, with the statistics
    and thresholds of Wang et al. 2018 (their Tables 1 and 3, Figure 3; docs/methods.md)."""
    from tqdm import tqdm

    from ..calib import METHODS, get_method
    from ..errors import CalibrationError
    from ..report.text import format_study, plot_study
    from ..solving.study import study_session

    ms = [m.strip().lower() for m in methods.split(",") if m.strip()]
    if not ms:
        raise CalibrationError(f"--methods: no method given; known: {', '.join(METHODS)}")
    for m in ms:
        get_method(m, "--methods")
    check_outputs({"--plot": plot}, [session_file], force)
    session = read_session_file(session_file, strict)
    total = len(ms) * max(0, n_max - 4)
    with tqdm(total=total, desc="solving", unit="solve", disable=None, file=sys.stderr,
              leave=False) as bar:
        res = study_session(session, ms, n_max=n_max, orthonormal=orthonormal,
                            progress=bar.update)
    if plot is not None:
        with output_files({"plot": plot}, force) as tmp:
            run_plot(plot_study, res, tmp["plot"], title=f"{session_file.name}: convergence")
    if as_json:
        print_json(res)
    else:
        click.echo(format_study(res))
        if plot is not None:
            click.echo(f"\nwrote {plot}")
