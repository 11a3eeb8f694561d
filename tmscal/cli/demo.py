"""``tmscal demo``: the whole job on a built-in mock rig (the packaged configs), through the
real drivers and wire protocols."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

import click

from ..net import split_endpoint
from .acquire_adaptive import adaptive_options, check_adaptive_flags
from .app import FORCE_HELP, INPUT_FILE, check_outputs, handle_errors, main, print_json


def _default_demo_config(name: str = "mock-ur-polaris.yaml") -> Path:
    """A built-in mock rig, ``name`` of the package data (``tmscal/data/configs/``; default
    ``mock-ur-polaris.yaml``), loaded through importlib.resources so it works from an
    installed wheel. Its ROM paths are relative to it: the whole folder must be on disk."""
    import atexit
    import contextlib
    from importlib.resources import as_file, files

    configs = files("tmscal.data") / "configs"
    if not isinstance(configs, Path):  # e.g. a zipped install: extract for this process
        stack = contextlib.ExitStack()
        atexit.register(stack.close)
        configs = stack.enter_context(as_file(configs))
    return Path(configs) / name


def demo_config_name(kinematics: bool = False) -> str:
    """The packaged config ``tmscal demo`` runs without ``--config``: the mock UR + Polaris
    (``mock-ur-polaris-kin.yaml`` with ``kinematics``), or the mock DENSO + Polaris where
    ur_rtde is not installed (no wheel for this platform; said on stderr), so that the demo
    runs from any plain ``pip install tmscal``."""
    from ..registry import get_spec

    if get_spec("ur", "robot").installed():
        return "mock-ur-polaris-kin.yaml" if kinematics else "mock-ur-polaris.yaml"
    click.echo("note: ur_rtde is not installed (pip install 'tmscal[ur]' builds it where PyPI "
               "has no wheel): the demo runs on the mock DENSO rig instead", err=True)
    return "mock-denso-polaris-kin.yaml" if kinematics else "mock-denso-polaris.yaml"


@main.command()
@click.option("--config", "config", type=INPUT_FILE, default=None,
              help="Mock rig config (default: the packaged mock-ur-polaris.yaml, in "
                   "tmscal/data/configs/; with --kinematics estimate, "
                   "mock-ur-polaris-kin.yaml, a UR5e with realistic arm errors; the mock-denso "
                   "ones where ur_rtde is not installed).")
@click.option("--kinematics", type=click.Choice(["estimate"]), default=None,
              help="Estimate the arm's kinematics with X, Y, Z (ml; docs/kinematics.md, "
                   "\"Using it\") instead of solving QR36 on the controller's poses, and "
                   "report the coil placement against the mock rig's truth through the flange "
                   "commands of the identified arm (true_coil_mm), beside QR36's on the "
                   "nominal arm. Not with --adaptive.")
@click.option("--poses", type=click.IntRange(3, 100000), default=None,
              help="Override plan.poses.")
@click.option("--samples", type=click.IntRange(1), default=None,
              help="Override sampling.samples.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Keep the session here (default: a temporary file).")
@click.option("--transport", type=click.Choice(["tcp", "pty"]), default="tcp",
              show_default=True,
              help="How the tracker mock is reached: loopback TCP (an NDI's socket://, an "
                   "OpenIGTLink host:port) or a pty (an NDI as a serial port; a tracker that "
                   "speaks TCP only stays on TCP).")
@click.option("--json", "as_json", is_flag=True,
              help="Print the solve result (with the mock rig's truth) as one JSON object; "
                   "with --adaptive (the solve is ml's, method ml) it adds robot_time_s "
                   "(moving, settling, sampling, total), poses_used, predicted_coil_mm, "
                   "true_coil_mm and stop_reason; with "
                   "--kinematics estimate it adds the arm, true_coil_mm and nominal "
                   "{method, true_coil_mm}.")
@click.option("-v", "--verbose", is_flag=True,
              help="With --kinematics estimate: list every combination of deviations, as "
                   "tmscal solve -v does.")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@adaptive_options
@handle_errors
def demo(config: Path | None, kinematics: str | None, poses: int | None, samples: int | None,
         output: Path | None, transport: str, as_json: bool, verbose: bool, force: bool,
         adaptive: bool, **overrides: Any) -> None:
    """The whole job on the built-in mock rig: start the mock robot and tracker, acquire
    through the real drivers and wire protocols, solve with QR36, compare with the truth.

    With --adaptive: the adaptive run (docs/adaptive.md), its robot time, and the session
    solved with the method whose prediction stopped the run (ml, distortion scale, not
    QR36): that calibration, its predicted coil-placement error and the true one against the
    mock rig's truth over the same region.
    With --kinematics estimate: ml with the arm's kinematics (docs/kinematics.md)."""
    from ..acquisition.run import acquire as run_acquire
    from ..config import load_config
    from ..mocks.launch import build_sim_rig, spawn_mock_rig
    from ..report.text import format_result, format_truth
    from ..session import read_session
    from ..solving.solve import solve
    from .progress import AcquireProgress, stderr_to_log

    if kinematics is not None and adaptive:
        raise click.BadParameter("--kinematics estimate solves the session once it is "
                                 "acquired; it does not go with --adaptive",
                                 param_hint="--kinematics")
    cfg_path = config or _default_demo_config(demo_config_name(kinematics is not None))
    check_adaptive_flags(adaptive, False, Path(), poses, overrides)
    check_outputs({"--output": output}, [cfg_path], force)
    # --force: the run replaces an existing session when its header is written (after the
    # mock rig answered); one another tmscal holds locked is refused (check_outputs)
    replace = output is not None and force
    cfg = load_config(cfg_path)
    truth = build_sim_rig(cfg).truth  # the child builds the same rig from the same config
    tmp = None
    if output is None:
        tmp = tempfile.TemporaryDirectory(prefix="tmscal-demo-")
        output = Path(tmp.name) / "demo-session.jsonl"
    try:
        if adaptive:
            from . import acquire_adaptive
            acquire_adaptive.demo(cfg, cfg_path, output, transport, samples, overrides, as_json,
                                  replace)
            return
        # the mocks run in a child process: ur_rtde holds the GIL while it waits for them
        with spawn_mock_rig(cfg_path, transport=transport) as mp:
            ep = mp.endpoints
            if not as_json:
                click.echo("mock rig: " + ", ".join(f"{k} {v}" for k, v in ep.items()))
            host, port = split_endpoint(ep["robot"])
            with stderr_to_log(), AcquireProgress(sys.stderr) as bar:
                res = run_acquire(cfg, output, poses=poses, samples=samples, replace=replace,
                                  tracker_port=ep["tracker"], robot_host=host,
                                  robot_port=port, progress=bar)
        session = read_session(output)
        session.header["truth"] = truth.as_dict()
        if kinematics is not None:
            from .demo_kinematics import demo_report
            demo_report(session, res, as_json, verbose)
            return
        result = solve(session, method="qr36")
        if as_json:
            print_json(result.to_json())
            return
        click.echo(f"acquired {res.recorded} poses ({res.skipped} skipped) in "
                   f"{res.elapsed_s:.1f} s through the wire protocols\n")
        click.echo(format_result(result))
        click.echo(format_truth(truth))
    finally:
        if tmp is not None:
            tmp.cleanup()

