"""``tmscal selfcal identify``: the arm identified from a recorded self-calibration session
(docs/selfcal.md, "Running it"), registered on the ``selfcal`` group of
:mod:`tmscal.cli.selfcal`. Thin: the session-level identification is
:mod:`tmscal.solving.selfcal`, the numerics :mod:`tmscal.calib.selfcal`, the kinematics file
:mod:`tmscal.formats.kinfile`."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import click

from .app import (
    FORCE_HELP,
    INPUT_FILE,
    STRICT_HELP,
    Finite,
    check_outputs,
    handle_errors,
    read_session_file,
    write_atomic,
)
from .selfcal import selfcal


def _shown(value: float, unit: str) -> tuple[float, str]:
    """A parameter value in edge units: rad → deg."""
    return (math.degrees(value), "deg") if unit == "rad" else (value, unit)


def _print_fit(res: Any) -> None:
    from ..solving.selfcal import CHANNEL_UNITS, CHANNELS

    if res.estimate is not None:
        _print_estimate(res)
    else:
        _print_kept(res)
    click.echo(f"{res.iterations} iterations; reduced χ² {res.reduced_chi2:.3g}")
    click.echo("residual RMS per channel (σ used): " + ", ".join(
        f"{c} {r:.3g} ({s:.2g}) {u}" for c, r, s, u in zip(CHANNELS, res.rms, res.sigma,
                                                            CHANNEL_UNITS, strict=True)))


def _print_estimate(res: Any) -> None:
    """The estimator's answer (form map): the combinations and the deviations it moved."""
    from ..report.text import wrench_fit_rows

    f, prior = res.estimate.fit, res.prior
    click.echo(f"estimator: every DH deviation (level {f.level}), prior ±"
               f"{prior['length_mm']:g} mm, ±{prior['angle_deg']:g}°, wrench rows only "
               "(the one kinematic estimator; docs/selfcal.md)")
    for combos, head in ((f.identified, "identified (σ_data ≥ 1)"),
                         (f.weak, "weakly identified (the prior decides)"),
                         (f.unidentified, "not identifiable, left at the nominal value")):
        if combos:
            click.echo(f"  {head}: {len(combos)}")
            for c in combos:
                click.echo(f"    {c.describe()}")
    click.echo("written: the MAP model of every deviation, independent of any choice of "
               "columns")
    moved = [(n, d, s) for n, d, s in zip(f.names, f.delta, f.sd, strict=True)
             if abs(d) > 1e-9 * (1.0 if n.startswith(("d_", "a_")) else 1e-3)]
    if moved:
        click.echo(f"  {'deviation':<14}{'nominal':>12}{'estimate':>12}{'± σ':>11}  unit")
        for n, _d, s in moved:
            unit = "mm" if n.startswith(("d_", "a_")) else "rad"
            a, u = _shown(res.model0.deviation(n), unit)
            b, _ = _shown(res.model.deviation(n), unit)
            e, _ = _shown(s, unit)
            click.echo(f"  {n:<14}{a:>12.5g}{b:>12.5g}{e:>11.2g}  {u}")
    for line in wrench_fit_rows(res.record()["wrench"]):
        click.echo(line)


def _print_kept(res: Any) -> None:
    """The paper's protocol (form kept): which columns QR pivoting kept, their fit."""
    model0, fit, ident = res.model0, res.fit, res.ident
    names, units = model0.parameter_names(), model0.parameter_units()
    p0, p1 = model0.vector(), res.model.vector()
    click.echo(f"identifiable: {len(ident.kept)} of {len(names)} parameters (condition "
               f"number {ident.cond:.3g}; QR pivoting rank {ident.qr_rank})")
    for n, why in ident.removed:
        click.echo(f"  not identified: {n}: {why}")
    click.echo("written: the fit of the kept columns (the others nominal)")
    click.echo(f"  {'parameter':<14}{'nominal':>12}{'estimate':>12}{'± σ':>11}  unit")
    for n, s in zip(fit.parameters, fit.std, strict=True):
        i = names.index(n)
        a, u = _shown(p0[i], units[i])
        b, _ = _shown(p1[i], units[i])
        e, _ = _shown(s * math.sqrt(res.scale), units[i])
        click.echo(f"  {n:<14}{a:>12.5g}{b:>12.5g}{e:>11.2g}  {u}")
    state = "converged" if fit.converged else "NOT converged (the iteration cap)"
    click.echo(f"  {state}")


@selfcal.command("identify")
@click.argument("session_file", metavar="SESSION", type=INPUT_FILE)
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Kinematics file (YAML) to write: the calibrated arm model, for "
                   "tmscal solve --kinematics.")
@click.option("--arm", default=None, metavar="NAME|FILE",
              help="The nominal model to start from: a registered name such as ur5e or "
                   "vs060, a shipped arm file's name, or the path of a URDF or arm file "
                   "(docs/kinematics.md, \"Arm files\"; default: the one the session was "
                   "acquired with).")
@click.option("--sigma", type=(Finite(0, lo_open=True), Finite(0, lo_open=True)),
              default=None, metavar="FORCE_N TORQUE_NM",
              help="Noise of the averaged wrench per force and torque channel (default: from "
                   "the session's recorded spreads).")
@click.option("--form", type=click.Choice(["map", "kept"]), default="map", show_default=True,
              help="The arm written: 'map' the one kinematic estimator with wrench rows only, "
                   "the maximum a posteriori model of every DH deviation under the --prior "
                   "(what the wrench does not see stays nominal; independent of any choice of "
                   "columns), 'kept' the fit of the columns QR pivoting keeps with the others "
                   "nominal (the protocol of Joubair et al. 2016).")
@click.option("--prior", type=(Finite(0, lo_open=True), Finite(0, lo_open=True)),
              default=(2.0, 1.0), show_default=True, metavar="LENGTH_MM ANGLE_DEG",
              help="The MAP form's prior (the estimator's tolerances): each length's and "
                   "angle's deviation from nominal.")
@click.option("--max-iter", type=click.IntRange(1, 1000), default=50, show_default=True,
              help="Iteration cap of the Gauss–Newton / Levenberg–Marquardt fit.")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@click.option("--strict", is_flag=True, help=STRICT_HELP)
@handle_errors
def identify(session_file: Path, output: Path, arm: str | None,
             sigma: tuple[float, float] | None, form: str, prior: tuple[float, float],
             max_iter: int, force: bool, strict: bool) -> None:
    """Identify the arm's kinematic parameters from a self-calibration session: the gravity
    wrenches a wrist force-torque sensor recorded at the recorded joints (Joubair et al.
    2016), rows weighted by each channel's noise. By default (--form map) with the one
    kinematic estimator of tmscal solve --kinematics estimate, wrench rows only: the maximum
    a posteriori deviation of every DH parameter under the --prior, with the combinations it
    identifies and why the others are not (docs/selfcal.md, "Running it"; docs/kinematics.md).
    --form kept is the paper's protocol: the columns QR pivoting keeps (Hollerbach & Wampler
    1996 scaling) fitted, the others nominal. Prints the estimates ± σ against the nominal
    values (angles in deg), the tool, bias and base tilt, the iterations and the residual RMS
    per channel, and writes the calibrated model to the kinematics file. The σ are scaled by
    the variance factor (the residuals against the stated noise)."""
    from ..formats.calibfile import provenance
    from ..formats.kinfile import kinematics_yaml
    from ..session import sha256_of
    from ..solving.selfcal import CHANNEL_UNITS, CHANNELS, identify_session

    check_outputs({"--output": output}, [session_file], force)
    session = read_session_file(session_file, strict)
    head = session.header.get("selfcal")
    name: Any = arm or (head.get("arm") if isinstance(head, dict) else None)
    if arm is None and isinstance(head, dict) and head.get("arm_definition") is not None:
        from ..formats.armdef import arm_from_record

        name = arm_from_record(head["arm_definition"],
                               f"{session_file}: header key 'selfcal.arm_definition'")
    if name is None:
        raise click.BadParameter(f"{session_file} does not name its arm; name the nominal "
                                 "model (a registered name such as ur5e or vs060)",
                                 param_hint="--arm")
    res = identify_session(session, name, sigma, form, prior[0], prior[1], max_iter,
                           "--arm" if arm else f"{session_file}: header 'selfcal.arm'")
    click.echo(f"{session_file}: {len(res.q)} configurations of arm {res.name}; channel σ from "
               f"{res.sigma_source}: " + ", ".join(
                   f"{c} {s:.2g} {u}" for c, s, u in zip(CHANNELS, res.sigma, CHANNEL_UNITS,
                                                        strict=True)))
    _print_fit(res)
    text = kinematics_yaml(res.model, identification=res.record(),
                           session={"path": str(session_file),
                                    "sha256": sha256_of(session_file)},
                           provenance=provenance(session.header))
    write_atomic(output, text, force)
    click.echo(f"wrote {output} (the calibrated arm model; tmscal solve SESSION "
               f"--kinematics {output})")
