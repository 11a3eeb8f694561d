"""``tmscal acquire``: record a session at the rig (or against ``tmscal mock``), its dry run
and its summary (``--adaptive`` is :mod:`tmscal.cli.acquire_adaptive`, ``--update``
:mod:`tmscal.cli.reregister`)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click

from .acquire_adaptive import adaptive_options, check_adaptive_flags
from .app import (
    EXIT_INTERRUPTED,
    INPUT_FILE,
    ROBOT_HOST_HELP,
    TRACKER_PORT_HELP,
    as_flags,
    check_outputs,
    fail,
    handle_errors,
    main,
    same_file,
)
from .check import calibration_origin
from .robot import RPY_CONVENTION, pose_line
from .stopping import StopFlag


@main.command()
@click.argument("config", type=INPUT_FILE)
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Session file (JSON Lines) to write or, with --resume, to continue.")
@click.option("--resume", is_flag=True,
              help="Continue an interrupted session: same plan, same P0, done poses skipped.")
@click.option("--poses", type=click.IntRange(3, 100000), default=None,
              help="Number of poses (overrides plan.poses); at least 3, the fewest a solve "
                   "takes.")
@click.option("--samples", type=click.IntRange(1), default=None,
              help="Distinct tracker frames averaged per pose (overrides sampling.samples).")
@click.option("--dry-run", is_flag=True,
              help="Print the plan's extent and estimated duration; move nothing.")
@click.option("--tracker-port", default=None, help=TRACKER_PORT_HELP)
@click.option("--robot-host", default=None, help=ROBOT_HOST_HELP)
@click.option("--force", is_flag=True,
              help="Record anew over an existing session at OUTPUT: it is replaced when the "
                   "new run's header is written, after the devices answered and the plan was "
                   "checked (a run that cannot start leaves it as it was), never one another "
                   "tmscal is recording; not with --resume.")
@click.option("--calib", "calib_file", type=INPUT_FILE, default=None, metavar="CALIB",
              help="Run around the P0 where this calibration was made (with plan.start: "
                   "current), not wherever the arm was left, so that the daily check and a "
                   "re-registration are measured where the calibration holds; the arm must "
                   "be inside the envelope around that P0 (tmscal robot CONFIG --calib CALIB "
                   "--move-to p0 takes it back). A fixed plan.start elsewhere is warned about. "
                   "docs/safety.md.")
@click.option("--update", "update", multiple=True, metavar="z|x|y|coil",
              help="With --calib: re-register only this transform at the rig (z: the tracker "
                   "moved, x: the marker on the coil, y: the coil's centre, coil: X and Y, the "
                   "coil re-seated; repeatable, e.g. --update z --update x): a few well-spread "
                   "poses around the calibration's P0, one at a time, until the update's "
                   "predicted coil-placement error at 95 % is at or below --target-mm "
                   "(default 0.1) or --max-poses (default 10) were measured; then writes the "
                   "updated calibration (--update-output, default OUTPUT with .yaml) as solve "
                   "--calib CALIB --update would, or refuses (exit 3, nothing written) when "
                   "the session shows a second change. docs/lab-day.md.")
@click.option("--update-output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              metavar="FILE", help="With --update: where the updated calibration is written.")
@adaptive_options
@handle_errors
def acquire(config: Path, output: Path, resume: bool, poses: int | None,
            samples: int | None, dry_run: bool, tracker_port: str | None,
            robot_host: str | None, force: bool, calib_file: Path | None,
            update: tuple[str, ...], update_output: Path | None, adaptive: bool,
            **overrides: Any) -> None:
    """Move the robot through the plan and record a session (A, B, C at every pose).

    Each pose: move, settle, average N distinct tracker frames (and the robot pose read
    alongside), append one fsynced line. Ctrl-C finishes the pose in flight and leaves a
    resumable session; device faults are retried with a reconnect.

    With --adaptive (the recommended way; docs/adaptive.md) the run measures a few
    well-spread poses, then after each pose predicts the coil-placement error and moves to
    the pose of the plan that reduces it most per second of robot time, until the prediction
    reaches --target-mm or --max-poses; it ends with the robot time by phase. --resume
    continues an adaptive session adaptively.
    """
    from ..acquisition.engine import AcquisitionStopped
    from ..acquisition.run import acquire as run_acquire
    from ..config import load_config
    from .progress import AcquireProgress, stderr_to_log

    if same_file(output, config):  # an existing session is the run's to resume, never this
        raise click.BadParameter(f"{output} is the config file; it is never written over",
                                 param_hint="--output")
    if force and resume:
        raise click.BadParameter("--force records the session anew; --resume continues it",
                                 param_hint="--force")
    if update or update_output is not None:
        from .reregister import acquire_update
        acquire_update(config, output, calib_file, update, update_output, resume, poses,
                       samples, dry_run, tracker_port, robot_host, force, adaptive, overrides,
                       StopFlag())
        return
    adaptive = check_adaptive_flags(adaptive, resume, output, poses, overrides)
    if calib_file is not None and resume:
        raise click.BadParameter("a resumed run keeps the P0 its session header records",
                                 param_hint="--calib")
    origin = calibration_origin(calib_file)
    cfg = load_config(config)
    if force and not dry_run:
        check_replaceable(output, config)
    if dry_run:
        settings = None
        if adaptive:  # the candidates: the plan with adaptive.pool poses
            from ..acquisition.adaptive_run import settings_for
            settings = settings_for(cfg, **overrides)
        _dry_run(cfg, poses, samples, robot_host, settings, tracker_port, origin)
        return
    stop = StopFlag()
    stop.install()
    if adaptive:
        _acquire_adaptive(cfg, config, output, resume, overrides, samples, tracker_port,
                          robot_host, stop, force, origin)
        return
    try:
        with stderr_to_log(), AcquireProgress(sys.stderr) as bar:
            res = run_acquire(cfg, output, resume=resume, replace=force, poses=poses,
                              samples=samples,
                              tracker_port=tracker_port, robot_host=robot_host,
                              progress=bar, should_stop=stop, origin=origin)
    except AcquisitionStopped as e:
        fail(f"acquisition stopped: {e}")
        return
    _acquire_summary(res, config, output, tracker_port, robot_host)
    if res.stopped:
        sys.exit(EXIT_INTERRUPTED)


def check_replaceable(output: Path, config: Path) -> None:
    """``--force`` of the acquiring commands, checked before anything connects: the session at
    ``output`` may be replaced by the one output rule (never an input, never a file another
    tmscal holds locked). The run replaces it only when its new header is written, after the
    devices answered and the plan was checked: a run that cannot start leaves it as it was."""
    check_outputs({"--output": output}, [config], True)


def _acquire_adaptive(cfg: Any, config: Path, output: Path, resume: bool,
                      overrides: dict[str, Any], samples: int | None,
                      tracker_port: str | None, robot_host: str | None, stop: Any,
                      replace: bool = False, origin: Any = None) -> None:
    from ..acquisition.engine import AcquisitionStopped
    from . import acquire_adaptive

    try:
        res = acquire_adaptive.run(cfg, output, resume=resume, overrides=overrides,
                               samples=samples, tracker_port=tracker_port,
                               robot_host=robot_host, should_stop=stop, replace=replace,
                               origin=origin)
    except AcquisitionStopped as e:
        fail(f"acquisition stopped: {e}")
        return
    acquire_adaptive.summary(res, config, output, tracker_port, robot_host)
    if res.stopped:
        sys.exit(EXIT_INTERRUPTED)


def _acquire_summary(res: Any, config: Path, output: Path, tracker_port: str | None = None,
                     robot_host: str | None = None) -> None:
    from ..acquisition.resume import resume_command

    state = "stopped early (resumable)" if res.stopped else "complete"
    click.echo(f"session {output}: {state}; {res.recorded} poses recorded, {res.skipped} "
               f"skipped, of {res.total} planned; {res.new_poses} new in "
               f"{res.elapsed_s:.1f} s; device faults recovered: {res.faults}")
    for note in res.notes:
        click.echo(f"note: {as_flags(note)}")
    if res.stopped:
        click.echo("resume with: " + resume_command(config, output, tracker_port, robot_host))
    click.echo(f"next: tmscal solve {output} --method qr36 -o {output.with_suffix('.yaml')}")


def _dry_run(cfg: Any, poses: int | None, samples: int | None, robot_host: str | None,
             adaptive: Any = None, tracker_port: str | None = None,
             origin: Any = None) -> None:
    """Print the dry run (``tmscal.acquisition.dryrun``): the tracker's offline checks, the
    run that will happen (an adaptive run's bootstrap, pose limit, target and robot time at
    most, then its candidates), the plan's extent and the envelope check, and what could not
    be checked without the robot. SafetyError when a pose or a move would be refused."""
    from ..acquisition.dryrun import dry_run
    from ..errors import SafetyError

    d = dry_run(cfg, poses, samples, robot_host, adaptive, tracker_port, origin)
    if d.tracker:
        click.echo("tracker (checked offline; nothing opened):")
        for line in d.tracker:
            click.echo(f"  {line}")
    a = d.adaptive
    if a is not None:
        click.echo(f"adaptive run (docs/adaptive.md): {a.bootstrap} well-spread bootstrap "
                   f"poses, then one chosen pose at a time; stops when the predicted "
                   f"coil-placement error is ≤ {a.target_mm:g} mm at {a.confidence * 100:g} %, "
                   f"at most {a.max_poses} poses (max_poses)")
        click.echo(f"  robot time at most {a.robot_time_max_s / 60:.1f} min: {a.max_poses} "
                   f"poses × (a move ≤ {a.longest_move_s:.1f} s + settling and sampling ≤ "
                   f"{a.per_pose_s:.1f} s), less when it reaches the target sooner (a pose "
                   "retried after a skip samples again)")
    if d.spec is None:
        click.echo(f"plan {cfg.plan.kind}: its poses need the robot")
    else:
        s = d.summary
        what = (f"the {a.pool} candidates (adaptive.pool) are the plan {d.spec.kind}"
                if a is not None else f"plan {d.spec.kind}: {d.spec.n} poses")
        click.echo(f"{what}, seed {d.spec.seed}, around P0 ({d.p0_source}):")
        if d.p0_known:
            click.echo("  P0 " + pose_line(d.spec.p0))
            click.echo(f"     angles: {RPY_CONVENTION}")
        frame = "" if d.p0_known else " (in P0's flange frame)"
        click.echo(f"  offsets from P0{frame}: x {s['x_range_mm'][0]:.1f}…"
                   f"{s['x_range_mm'][1]:.1f}, y {s['y_range_mm'][0]:.1f}…"
                   f"{s['y_range_mm'][1]:.1f}, z {s['z_range_mm'][0]:.1f}…"
                   f"{s['z_range_mm'][1]:.1f} mm; max {s['offset_max_mm']:.1f} mm")
        click.echo(f"  rotation from P0: max {s['rotation_max_deg']:.2f} deg")
        if d.p0_known:
            _extent_rows(s)
        if a is None:  # an adaptive run's time is its line above, not the candidates'
            click.echo(f"  estimated duration: {s['duration_s'] / 60:.1f} min (travel "
                       f"{s['travel_mm'] / 1000:.1f} m = {s['motion_s']:.0f} s at "
                       f"{d.speed_mm_s:g} mm/s, sampling {s['sampling_s']:.0f} s)")
    for line in d.not_checked:
        click.echo(f"  {line}")
    if d.refusal is not None:
        raise SafetyError(d.refusal)
    if d.spec is None:
        return
    if not d.p0_known:
        click.echo("  safety envelope: every pose within the offset and rotation limits from "
                   "P0; the box and the paths are checked when the run starts, before "
                   "anything moves (docs/safety.md)")
        return
    split = (f"; {len(d.split_moves)} move(s) leave on the straight path and go through P0 "
             f"(to pose {', '.join(map(str, d.split_moves[:8]))}"
             f"{', …' if len(d.split_moves) > 8 else ''})" if d.split_moves else "")
    click.echo(f"  safety envelope: every pose inside, every move's path inside{split} "
               "(docs/safety.md)")


def _extent_rows(s: dict[str, Any]) -> None:
    """The workspace box and the flange's and tool points' extent over the plan, in the
    robot base frame (mm)."""
    click.echo(f"  {'in the robot base frame (mm)':<32} {'x':^16}{'y':^16}{'z':^16}")
    for label, key in (("workspace box (safety)", "box"), ("flange over the plan", "flange"),
                       ("tool points over the plan", "tool")):
        lo, hi = s[f"{key}_min_mm"], s[f"{key}_max_mm"]
        if lo is not None:
            cells = "".join(f"{a:8.1f}…{b:<7.1f}" for a, b in zip(lo, hi))
            click.echo(f"    {label:<30} {cells}")
    if s["tool_min_mm"] is None:
        click.echo("    (no safety.tool_points_mm: the box bounds the flange only)")
