"""``tmscal compare``: every calibration method side by side on one session (the comparison of
the Panda/Vicra TMS study; docs/methods.md)."""

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

#: the files ``--plot DIR`` writes
PLOT_FILES = {"errors": "compare-errors.png", "time": "compare-time.png",
              "truth": "compare-truth.png"}


def _int_list(opt: str, text: str | None) -> list[int] | None:
    if text is None:
        return None
    try:
        vals = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise click.BadParameter(f"{text!r}: expected whole numbers separated by commas",
                                 param_hint=opt) from None
    if not vals:
        raise click.BadParameter("no pose count given", param_hint=opt)
    return vals


@main.command()
@click.argument("session_file", type=INPUT_FILE)
@click.option("--methods", default=None,
              help="Comma-separated methods to compare (default: every registered method; "
                   "see tmscal solve --help). Methods that need probe poses are skipped, "
                   "with a note, on a marker-only session.")
@click.option("--n", "n_text", default=None, metavar="N[,N…]",
              help="Pose counts to solve on, comma-separated (default: 5, 7, 10, 14, 20, 30, "
                   "50, 100, 150, 250, 500 up to what the folds leave, and that maximum).")
@click.option("--folds", type=click.IntRange(2, 100), default=5, show_default=True,
              help="The poses are cut in order into K contiguous folds; each is held out in "
                   "turn and the method solved on the first n poses outside it. Errors are "
                   "the mean ± SD over folds.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--plot", type=click.Path(file_okay=False, path_type=Path), default=None,
              metavar="DIR",
              help="Write the figures into DIR (created if missing): "
                   f"{PLOT_FILES['errors']} (held-out position and orientation error against "
                   f"n, one colour per method), {PLOT_FILES['time']} (solve time against n) "
                   f"and, with a truth in the session, {PLOT_FILES['truth']}.")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@click.option("--strict", is_flag=True, help=STRICT_HELP)
@handle_errors
def compare(session_file: Path, methods: str | None, n_text: str | None, folds: int,
            as_json: bool, plot: Path | None, force: bool, strict: bool) -> None:
    """Compare the calibration methods on one session: held-out position and orientation
    error (mean ± SD over folds) and solve time against the number of poses, per method, as
    the Panda/Vicra TMS study compared QR24, SGO and QUAT (docs/methods.md). With a truth
    in the session (tmscal simulate), the ground-truth error of Y (X on a marker-only session),
    the coil placement error and, when available, the Cramér–Rao bound beside them."""
    from tqdm import tqdm

    from ..report.plots import plot_compare
    from ..solving.compare import compare_session

    ms = None if methods is None else [m.strip() for m in methods.split(",") if m.strip()]
    if ms is not None and not ms:
        raise click.BadParameter("no method given", param_hint="--methods")
    ns = _int_list("--n", n_text)
    outputs = {f"--plot ({name})": None if plot is None else plot / f
               for name, f in PLOT_FILES.items()}
    check_outputs(outputs, [session_file], force)
    session = read_session_file(session_file, strict)
    with tqdm(desc="solving", unit="solve", disable=None, file=sys.stderr,
              leave=False) as bar:
        res = compare_session(session, ms, ns=ns, folds=folds, progress=bar.update)
    written = []
    if plot is not None:
        plot.mkdir(parents=True, exist_ok=True)
        files = {k.split("(")[1].rstrip(")"): v for k, v in outputs.items()
                 if v is not None and (res["truth"] or "truth" not in k)}
        with output_files(files, force) as tmp:
            run_plot(plot_compare, res, tmp, title=session_file.name)
        written = [str(v) for v in files.values()]
    if as_json:
        from ..session import json_safe
        print_json(json_safe(res))
    else:
        from ..report.compare import format_compare
        click.echo(format_compare(res))
        for p in written:
            click.echo(f"wrote {p}")
