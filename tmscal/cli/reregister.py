"""``tmscal acquire CONFIG -o TODAY --calib CAL --update z``: the re-registration at the rig
(:mod:`tmscal.acquisition.reregister`, docs/lab-day.md "Re-registering at the rig"), then the
update of ``solve --calib --update`` on its session, written beside it. The options are the
``acquire`` command's (:mod:`tmscal.cli.acquire`)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click

from .app import EXIT_INTERRUPTED, as_flags, check_outputs, fail

__all__ = ["acquire_update"]


def acquire_update(config: Path, output: Path, calib_file: Path | None,
                   update: tuple[str, ...], update_output: Path | None, resume: bool,
                   poses: int | None, samples: int | None, dry_run: bool,
                   tracker_port: str | None, robot_host: str | None, force: bool,
                   adaptive: bool, overrides: dict[str, Any], stop: Any) -> None:
    """``acquire --calib CAL --update NAME``: the re-registration run
    (``acquisition.reregister``), then the update of ``solve --calib --update`` on its
    session (``check._update``), written to ``update_output``. Every refusal of the
    options comes before anything connects; ``stop`` (the rig commands' StopFlag) is installed
    just before."""
    from ..acquisition.engine import AcquisitionStopped
    from ..acquisition.reregister import ReregisterSettings, reregister
    from ..check import noise_of
    from ..config import load_config
    from ..errors import CalibrationError
    from ..formats.calibfile import read_calibration
    from .check import _update, calibration_origin
    from .progress import AcquireProgress, stderr_to_log

    if not update:
        raise click.BadParameter("only with --update", param_hint="--update-output")
    if calib_file is None:
        raise click.BadParameter("--update re-registers a stored calibration: give --calib "
                                 "CALIB", param_hint="--update")
    for opt, given in (("--resume", resume), ("--adaptive", adaptive),
                       ("--poses", poses is not None), ("--dry-run", dry_run),
                       ("--confidence/--bootstrap", overrides.get("confidence") is not None
                        or overrides.get("bootstrap") is not None)):
        if given:
            raise click.BadParameter("not with --update (it chooses its poses and stops at "
                                     "--target-mm or --max-poses)", param_hint=opt)
    try:
        settings = ReregisterSettings(
            tuple(update), **{k: v for k, v in (("target_mm", overrides.get("target_mm")),
                                                ("max_poses", overrides.get("max_poses")))
                              if v is not None})
    except CalibrationError as e:
        raise click.BadParameter(str(e), param_hint="--update") from None
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--max-poses") from None
    new = update_output or output.with_suffix(".yaml")
    check_outputs({"--output": output, "--update-output": new}, [config, calib_file], force)
    origin = calibration_origin(calib_file)
    cf = read_calibration(calib_file)
    cfg = load_config(config)
    tools = cfg.tracker.tools if cfg.tracker else {}
    bodies = ("marker", "probe") if cf.calibration.Y is not None and "probe" in tools \
        else ("marker",)
    noise = noise_of(cf, bodies)
    stop.install()
    try:
        with stderr_to_log(), AcquireProgress(sys.stderr) as bar:
            res = reregister(cfg, output, cf.calibration, noise, settings, origin,
                             replace=force, samples=samples, tracker_port=tracker_port,
                             robot_host=robot_host, progress=bar, should_stop=stop)
    except AcquisitionStopped as e:
        fail(f"acquisition stopped: {e}")
        return
    rt = (res.robot_time_s or {}).get("total")
    click.echo(f"session {output}: {res.recorded} poses in {res.elapsed_s:.1f} s"
               + (f" ({rt:.1f} s of robot time)" if rt is not None else "")
               + f"; {res.message}")
    for note in res.notes:
        click.echo(f"note: {as_flags(note)}")
    if res.stopped:
        click.echo(f"stopped early; re-register from what was recorded with: tmscal solve "
                   f"{output} --calib {calib_file} --update {' --update '.join(update)} -o "
                   f"{new}")
        sys.exit(EXIT_INTERRUPTED)
    _update(output, calib_file, list(update), False, False, new, False, force)
