"""``tmscal selfcal acquire``: the rig side of the kinematic self-calibration (docs/selfcal.md,
"Running it"), registered on the ``selfcal`` group of :mod:`tmscal.cli.selfcal`. Thin: the loop
is :mod:`tmscal.acquisition.selfcal`."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click
import numpy as np

from ..acquisition.progress import Progress
from .app import (
    EXIT_INTERRUPTED,
    INPUT_FILE,
    ROBOT_HOST_HELP,
    Finite,
    fail,
    handle_errors,
    same_file,
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
@click.option("--arm", default=None, metavar="NAME|FILE",
              help="The arm's nominal model: a registered name such as ur5e, vs060 or fr3, a "
                   "shipped arm file's name, or the path of a URDF or arm file (the session "
                   "keeps its definition; docs/kinematics.md, \"Arm files\"; default: the "
                   "config's mock.kinematics.arm on a mock rig; required at a real one).")
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
