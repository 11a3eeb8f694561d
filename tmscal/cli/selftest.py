"""``tmscal selftest --rig CONFIG``: the rig acceptance checks (``docs/acceptance.md``) from an
installed tmscal, the same checks and report as ``pytest tests/acceptance --rig CONFIG``
(:class:`tmscal.acceptance.rig.RigSelftest`)."""

from __future__ import annotations

from pathlib import Path

import click

from .app import (
    EXIT_CHECK_FAILED,
    EXIT_INTERRUPTED,
    FORCE_HELP,
    INPUT_FILE,
    Finite,
    check_outputs,
    handle_errors,
    main,
    write_atomic,
)


@main.command()
@click.option("--rig", "config", type=INPUT_FILE, required=True, metavar="CONFIG",
              help="The rig config to check (the one you run acquire with). A config with a "
                   "mock: section is served by mocks started for the checks (unless "
                   "--no-start-mocks).")
@click.option("--report", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Where to write the report (default: acceptance-report-<date>.txt in the "
                   "current folder, -2, -3 … added rather than overwriting an earlier one).")
@click.option("--no-start-mocks", is_flag=True,
              help="A config with a mock: section is served by mocks already running "
                   "(tmscal mock CONFIG).")
@click.option("--rate-tolerance", type=Finite(0, lo_open=True), default=0.10,
              show_default=True, metavar="FRACTION",
              help="How far the measured tracker frame rate may be from "
                   "tracker.frame_rate_hz, as a fraction (judged on a real-time device only).")
@click.option("--frames", type=click.IntRange(2), default=100, show_default=True,
              help="Distinct tracker frames read by the tool-visibility check.")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@handle_errors
def selftest(config: Path, report: Path | None, no_start_mocks: bool, rate_tolerance: float,
             frames: int, force: bool) -> None:
    """Run the acceptance checks on the devices of a rig config: connect and identity, tool
    visibility and frame rate, a small move inside the envelope and back, stop while moving,
    reconnect. THE ROBOT MOVES (10 mm, then 40 mm stopped midway): see docs/acceptance.md.
    Prints each verdict, writes the report; exit 0 when no check failed, 3 when one did."""
    from ..acceptance.checks import CHECK_NAMES, result_text
    from ..acceptance.rig import RigSelftest, default_report_path
    from ..config import load_config

    check_outputs({"--report": report}, [config], force)
    out = report if report is not None else default_report_path()
    start = load_config(config).mock is not None and not no_start_mocks
    mocks = None
    if start:
        from ..mocks.launch import spawn_mock_rig
        mocks = spawn_mock_rig(config, transport="tcp")
    interrupted = False
    try:
        with RigSelftest(config, mocks.endpoints if mocks else None, started_mocks=start,
                         frames=frames, rate_tolerance=rate_tolerance) as st:
            try:
                for key in CHECK_NAMES:
                    click.echo(st.run(key).summary())
            except KeyboardInterrupt:
                interrupted = True
                click.echo("interrupted: the devices are stopped and closed; the report holds "
                           "the checks run so far", err=True)
        write_atomic(out, st.report(), force=report is not None and force)
    finally:
        if mocks is not None:
            mocks.close()
    click.echo(f"\nresult: {result_text(st.checks)}; the measured values are in the report"
               f"\nreport written to {out}")
    if interrupted:
        raise SystemExit(EXIT_INTERRUPTED)
    if not st.passed:
        raise SystemExit(EXIT_CHECK_FAILED)
