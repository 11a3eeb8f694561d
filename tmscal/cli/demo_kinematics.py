"""``tmscal demo --kinematics estimate``: the session acquired on the mock rig solved with the
arm's kinematics estimated (``solving.solve(session, method="ml", kinematics="estimate")``,
docs/kinematics.md), and the coil placement against the mock rig's truth through that
calibration's flange commands, beside QR36's on the controller's nominal poses. The command's
options live in :mod:`tmscal.cli.demo`."""

from __future__ import annotations

from typing import Any

import click


def demo_report(session: Any, acquired: Any, as_json: bool, verbose: bool = False) -> None:
    """Solve ``session`` (its header carrying the mock rig's truth) with --kinematics
    estimate and with QR36, and print the result: the ``tmscal solve`` text with the arm,
    then the two true coil placements (mm); or with ``as_json`` the solve JSON plus
    ``true_coil_mm`` and ``nominal`` {method, true_coil_mm}. ``acquired``: the acquisition's
    result (poses recorded, skipped, seconds). ``verbose``: list every combination of
    deviations (``report.text.format_result``)."""
    from ..report.text import format_result
    from ..solving.solve import solve
    from .app import print_json

    result = solve(session, method="ml", kinematics="estimate")
    nominal = solve(session, method="qr36")

    def coil(res: Any) -> float | None:
        t = res.truth or {}
        return t.get("coil_placement_mm")

    if as_json:
        print_json({**result.to_json(), "true_coil_mm": coil(result),
                     "nominal": {"method": "qr36", "true_coil_mm": coil(nominal)}})
        return
    click.echo(f"acquired {acquired.recorded} poses ({acquired.skipped} skipped) in "
               f"{acquired.elapsed_s:.1f} s through the wire protocols\n")
    click.echo(format_result(result, verbose=verbose))
    ours, theirs = coil(result), coil(nominal)
    if ours is not None and theirs is not None:
        click.echo(f"\ntrue coil placement, mean over the session's {result.n_test} probe "
                   f"poses as targets:\n  {ours:.4f} mm with the estimated arm's flange "
                   f"commands\n  {theirs:.4f} mm with QR36 on the controller's nominal poses")
