"""``tmscal selfcal acquire`` and ``tmscal selfcal identify``: the rig side of the kinematic
self-calibration (docs/selfcal.md, "Running it"), registered on the ``selfcal`` group of
:mod:`tmscal.cli.selfcal`. Thin: the loop is :mod:`tmscal.acquisition.selfcal`, the numerics
:mod:`tmscal.calib.selfcal`, the kinematics file :mod:`tmscal.formats.kinfile`."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import click
import numpy as np

from ..acquisition.progress import Progress
from .app import (
    EXIT_INTERRUPTED,
    FORCE_HELP,
    INPUT_FILE,
    ROBOT_HOST_HELP,
    STRICT_HELP,
    Finite,
    check_outputs,
    fail,
    handle_errors,
    read_session_file,
    same_file,
    write_atomic,
)
from .selfcal import selfcal


def _arm_name(arm: str | None, cfg: Any) -> str | None:
    """--arm, else the arm of the config's mock kinematics (a mock rig), else None."""
    if arm is not None:
        return arm
    kin = getattr(getattr(cfg, "mock", None), "kinematics", None)
    return kin.get("arm") if isinstance(kin, dict) else None


@selfcal.command("acquire")
@click.argument("config", type=INPUT_FILE)
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Session file (JSON Lines) to write or, with --resume, to continue.")
@click.option("--resume", is_flag=True,
              help="Continue an interrupted session: the plan is in its header; the "
                   "configurations already recorded are skipped.")
@click.option("--arm", default=None,
              help="The arm's nominal model, a registered name such as ur5e, vs060 or fr3 "
                   "(docs/kinematics.md; default: the config's mock.kinematics.arm on a mock "
                   "rig; required at a real one).")
@click.option("--k", "k", type=click.IntRange(1, 10000), default=60, show_default=True,
              help="Configurations to visit, chosen by DETMAX (maximal det JᵀJ, i.e. O1).")
@click.option("--pool", type=click.IntRange(1, 100000), default=5000, show_default=True,
              help="Candidate configurations drawn around the arm's joints; those whose "
                   "flange pose leaves the safety envelope are dropped.")
@click.option("--span-deg", type=Finite(0, 180, lo_open=True), default=90.0,
              show_default=True,
              help="Candidates turn the wrist joints up to ± this (deg) from where they are "
                   "now, the other joints up to a third of it.")
@click.option("--seed", type=click.IntRange(0, 2**32 - 1), default=0, show_default=True,
              help="Seed of the candidates and of DETMAX.")
@click.option("--samples", type=click.IntRange(1, 100000), default=None,
              help="Force-torque readings averaged per configuration (default: ft.samples).")
@click.option("--robot-host", default=None, help=ROBOT_HOST_HELP)
@click.option("--ft-host", default=None, metavar="HOST[:PORT]",
              help="Force-torque sensor address (overrides ft.host and ft.port).")
@click.option("--dry-run", is_flag=True,
              help="Connect to the robot, make the plan and check it against the safety "
                   "envelope; move nothing, write nothing.")
@click.option("--force", is_flag=True,
              help="Record anew over an existing session at OUTPUT: it is replaced when the "
                   "new run's header is written, after the devices answered and the plan was "
                   "checked (a run that cannot start leaves it as it was), never one another "
                   "tmscal is recording; not with --resume.")
@handle_errors
def acquire(config: Path, output: Path, resume: bool, arm: str | None, k: int, pool: int,
            span_deg: float, seed: int, samples: int | None, robot_host: str | None,
            ft_host: str | None, dry_run: bool, force: bool) -> None:
    """Move the robot through configurations chosen for self-calibration and record, at each,
    the joint angles and the averaged wrist force-torque reading (a session; docs/selfcal.md).

    The candidates are checked against the config's safety envelope before anything moves;
    every move is a Cartesian flange pose (the nominal model's) sent through the same checked
    move as `tmscal acquire`. Each configuration: move, wait sampling.settle_s, read the
    joints, average the F/T readings, append one fsynced line. Ctrl-C finishes the
    configuration in flight and leaves a resumable session; device faults are retried with a
    reconnect. Then: tmscal selfcal identify SESSION -o KIN.yaml."""
    from ..acquisition.engine import AcquisitionStopped
    from ..acquisition.progress import ProgressGroup
    from ..acquisition.resume import resume_command
    from ..acquisition.selfcal import acquire_selfcal
    from ..config import load_config
    from ..net import split_endpoint
    from .acquire import check_replaceable
    from .progress import AcquireProgress, stderr_to_log
    from .stopping import StopFlag

    if same_file(output, config):
        raise click.BadParameter(f"{output} is the config file; it is never written over",
                                 param_hint="--output")
    if force and resume:
        raise click.BadParameter("--force records the session anew; --resume continues it",
                                 param_hint="--force")
    cfg = load_config(config, check_files=False)  # no tracker needed
    name = _arm_name(arm, cfg)
    if name is None and not resume:
        raise click.BadParameter("name the arm's nominal model (a registered name such as "
                                 "ur5e or vs060; docs/kinematics.md)", param_hint="--arm")
    if dry_run:
        _dry_run(cfg, name, k, pool, seed, span_deg, robot_host)
        return
    if force:
        check_replaceable(output, config)
    try:
        ft_addr = split_endpoint(ft_host) if ft_host else (None, None)
    except ValueError:
        raise click.BadParameter(f"{ft_host!r}: expected HOST or HOST:PORT",
                                 param_hint="--ft-host") from None
    stop = StopFlag()
    stop.install()
    try:
        with stderr_to_log(), AcquireProgress(sys.stderr, label="configuration") as bar:
            res = acquire_selfcal(cfg, output, arm=name, k=k, pool=pool, seed=seed,
                                  span_deg=span_deg, resume=resume, replace=force,
                                  samples=samples,
                                  robot_host=robot_host, ft_host=ft_addr[0],
                                  ft_port=ft_addr[1], progress=ProgressGroup(PlanLine(), bar),
                                  should_stop=stop)
    except AcquisitionStopped as e:
        fail(f"acquisition stopped: {e}")
        return
    state = "stopped early (resumable)" if res.stopped else "complete"
    click.echo(f"session {output}: {state}; {res.recorded} of {res.total} configurations "
               f"recorded, {res.new_poses} new in {res.elapsed_s:.1f} s; device faults "
               f"recovered: {res.faults}")
    if res.stopped:
        click.echo("resume with: " + resume_command(config, output, robot_host=robot_host,
                                                    ft_host=ft_host, command="selfcal acquire"))
        sys.exit(EXIT_INTERRUPTED)
    click.echo(f"next: tmscal selfcal identify {output} -o {output.with_suffix('.kin.yaml')}")


def _echo_plan(plan: Any) -> None:
    click.echo(f"plan: {len(plan.q)} configurations of arm {plan.arm}, chosen from "
               f"{plan.inside} of {plan.pool} candidates inside the safety envelope (wrist "
               f"±{plan.span_deg:g}°), for {len(plan.identifiable)} identifiable parameters; "
               f"O1 {plan.o1:.3g}")
    sys.stdout.flush()


class PlanLine(Progress):
    """The self-calibration plan (a ``SelfcalPlan``) on stdout before anything moves."""

    def planned(self, plan: Any) -> None:
        _echo_plan(plan)


def _dry_run(cfg: Any, arm: str | None, k: int, pool: int, seed: int, span_deg: float,
             robot_host: str | None) -> None:
    """The plan from where the arm is now, checked against the envelope; nothing moves."""
    from ..acquisition.devices import envelope_for, make_robot
    from ..acquisition.selfcal import nominal_arm, plan_selfcal
    from ..errors import ConfigError

    model = nominal_arm(arm or "")
    with make_robot(cfg, envelope_for(cfg, None), robot_host) as rb:
        try:
            p0, q0 = rb.flange_pose(), np.asarray(rb.joint_positions(), dtype=float)
        except NotImplementedError as e:
            raise ConfigError(f"{cfg.path}: key 'robot.driver': {e}; self-calibration "
                              "needs the joint angles") from None
    plan = plan_selfcal(model, q0, p0, envelope_for(cfg, p0), k, pool, seed, span_deg)
    _echo_plan(plan)
    turn = np.degrees(np.abs(plan.q - q0).max(axis=0))
    click.echo("  largest joint change from now (deg): "
               + ", ".join(f"J{j + 1} {t:.0f}" for j, t in enumerate(turn)))
    click.echo("  safety envelope: every pose inside; nothing was moved (dry run)")


# --- identify ---------------------------------------------------------------------------------

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
@click.option("--arm", default=None,
              help="The nominal model to start from, a registered name such as ur5e or "
                   "vs060 (docs/kinematics.md; default: the one the session was acquired "
                   "with).")
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
    name = arm or (head.get("arm") if isinstance(head, dict) else None)
    if name is None:
        raise click.BadParameter(f"{session_file} does not name its arm; name the nominal "
                                 "model (a registered name such as ur5e or vs060)",
                                 param_hint="--arm")
    res = identify_session(session, name, sigma, form, prior[0], prior[1], max_iter,
                           "--arm" if arm else f"{session_file}: header 'selfcal.arm'")
    click.echo(f"{session_file}: {len(res.q)} configurations of arm {name}; channel σ from "
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
