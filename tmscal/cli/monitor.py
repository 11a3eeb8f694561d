"""``tmscal monitor``: the live health monitor of a calibrated rig (the loop is
:mod:`tmscal.monitor`, the rule :mod:`tmscal.calib.alarm`; docs/lab-day.md, "Monitor")."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click

from .app import (
    EXIT_CHECK_FAILED,
    INPUT_FILE,
    ROBOT_HOST_HELP,
    TRACKER_PORT_HELP,
    Finite,
    handle_errors,
    main,
    print_json,
)

if TYPE_CHECKING:
    from ..monitor import MonitorEvent


@main.command()
@click.argument("config", type=INPUT_FILE)
@click.option("--calib", "calib_file", type=INPUT_FILE, required=True, metavar="CALIB",
              help="The calibration to hold the rig against: a file written by `tmscal solve "
                   "-o` (its noise model sets the alarm's bound).")
@click.option("--json", "as_json", is_flag=True,
              help="One JSON object per event on stdout (and a summary object at the end).")
@click.option("--stop-robot", is_flag=True,
              help="At an alarm, call the robot driver's stop (the monitor never moves it).")
@click.option("--level", type=Finite(0, 0.5, lo_open=True), default=1e-6,
              show_default=True,
              help="False-alarm probability of one still phase of an unchanged rig (the χ² "
                   "bound from the calibration's noise model).")
@click.option("--tolerance-mm", type=Finite(0, lo_open=True), default=None,
              help="Alarm only for a change whose mean residual translation exceeds this "
                   "(mm; or --tolerance-deg). Default: any change significant at --level.")
@click.option("--tolerance-deg", type=Finite(0, lo_open=True), default=None,
              help="Likewise for the rotation (degrees).")
@click.option("--window", "window_s", type=Finite(0, 10, lo_open=True), default=0.25,
              show_default=True, metavar="S", help="Seconds of tracker frames averaged.")
@click.option("--persistence", "persistence_s", type=Finite(0, 60, lo_open=True),
              default=None, metavar="S",
              help="Seconds over the bound before the alarm (default: the window and one "
                   "frame, so that one bad frame cannot raise it).")
@click.option("--settle", "settle_s", type=Finite(0, 60), default=1.0, show_default=True,
              metavar="S", help="Seconds after the robot stops before frames are checked "
                                "(the coil's swing).")
@click.option("--latency", "latency_s", type=Finite(0, 5), default=0.1, show_default=True,
              metavar="S", help="Bound on the delay between the robot's and the tracker's "
                                "readings: a frame is checked only if the robot was still "
                                "this long after it too.")
@click.option("--out-of-view", "out_of_view_s", type=Finite(0, 3600, lo_open=True),
              default=2.0, show_default=True, metavar="S",
              help="Report a tool unusable for longer than this.")
@click.option("--port", type=click.IntRange(0, 65535), default=18944, show_default=True,
              help="TCP port of the OpenIGTLink server sending STATUS messages (0: a free "
                   "port, printed on stderr at start).")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address of the OpenIGTLink server. Loopback unless --allow-remote.")
@click.option("--allow-remote", is_flag=True,
              help="Allow a --host that is not a loopback address (prints a warning).")
@click.option("--wait-client", "wait_client_s", type=Finite(0, 3600, lo_open=True),
              default=None, metavar="S",
              help="Before reading any frame, wait up to S seconds for an OpenIGTLink client "
                   "to connect (an error when none does).")
@click.option("--frames", type=click.IntRange(1), default=None,
              help="Stop after this many tracker frames (default: until Ctrl-C).")
@click.option("--tracker-port", default=None, help=TRACKER_PORT_HELP)
@click.option("--robot-host", default=None, help=ROBOT_HOST_HELP)
@handle_errors
def monitor(config: Path, calib_file: Path, as_json: bool, stop_robot: bool, level: float,
            tolerance_mm: float | None, tolerance_deg: float | None, window_s: float,
            persistence_s: float | None, settle_s: float, latency_s: float,
            out_of_view_s: float, port: int, host: str, allow_remote: bool,
            wait_client_s: float | None, frames: int | None, tracker_port: str | None,
            robot_host: str | None) -> None:
    """Watch a calibrated rig during a session: at the tracker's frame rate, check A X
    against Z B (and A Y against Z C where the probe is seen) in the robot's still phases,
    and raise an alarm naming what moved when the residual stays beyond the calibration's
    noise. Events go to stdout (--json: one object each) and to OpenIGTLink clients as
    STATUS messages (device TMSCalMonitor); tools out of view are reported too. The robot
    is never moved (--stop-robot: stopped at an alarm). Exit status 3 when an alarm was
    raised, 0 otherwise; a device that disappears is an error (exit 1). Ctrl-C stops."""
    from ..acquisition.devices import Devices, Endpoints
    from ..config import load_config
    from ..errors import DeviceTimeout
    from ..formats.calibfile import read_calibration
    from ..monitor import MonitorSettings, run_monitor
    from ..stream import StreamServer
    from ..timing import Deadline
    from .stopping import StopFlag, close_quietly
    from .stream import _check_host

    _check_host(host, allow_remote)
    settings = MonitorSettings(window_s=window_s, persistence_s=persistence_s, level=level,
                               tolerance_mm=tolerance_mm, tolerance_deg=tolerance_deg,
                               settle_s=settle_s, latency_s=latency_s,
                               out_of_view_s=out_of_view_s, stop_robot=stop_robot)
    cfg = load_config(config)
    cf = read_calibration(calib_file)
    if cfg.robot is None or cfg.tracker is None:
        raise click.UsageError(f"{config}: the monitor needs a robot and a tracker section")
    dev = Devices(cfg, "tracker", Endpoints(tracker_port=tracker_port, robot_host=robot_host))
    try:
        server = StreamServer(host, port)
    except OSError as e:
        raise click.BadParameter(f"cannot listen on {host}:{port}: {e.strerror or e}",
                                 param_hint="--port/--host") from None
    stop = StopFlag(quiet=True)
    stop.install()

    def on_event(ev: MonitorEvent) -> None:
        if as_json:
            print_json(ev.to_json())
        else:
            click.echo(ev.message)
        sys.stdout.flush()

    interrupted = False
    mon = None
    try:
        server.start()
        click.echo(f"OpenIGTLink STATUS server on {server.host}:{server.port}", err=True)
        sys.stderr.flush()
        if wait_client_s is not None:
            d = Deadline(wait_client_s)
            while not server.is_connected():
                if d.expired():
                    raise DeviceTimeout(f"no OpenIGTLink client connected to "
                                        f"{server.host}:{server.port} within "
                                        f"{wait_client_s:g} s (--wait-client)")
                time.sleep(0.02)
        dev.open()
        assert dev.robot is not None and dev.tracker is not None
        mon = run_monitor(dev.robot, dev.tracker, cf, settings, server=server, frames=frames,
                          stop=stop, on_event=on_event)
    except KeyboardInterrupt:
        interrupted = True
        click.echo("stopped", err=True)
    finally:
        server.stop()
        if interrupted:
            close_quietly(dev)
        else:
            dev.close()
    if mon is None:
        return
    summary = mon.summary()
    if as_json:
        print_json({"event": "summary", **summary})
    else:
        click.echo(f"monitor stopped: {summary['frames']} frames ({summary['seconds']:.1f} s "
                   f"of tracker time), {summary['checked']} checked in still phases, "
                   f"{summary['alarms']} alarm(s)")
    if summary["alarms"]:
        sys.exit(EXIT_CHECK_FAILED)
