"""``tmscal stream``: live OpenIGTLink TRANSFORM messages of the tracked coil through a stored
calibration, for 3D Slicer's OpenIGTLinkIF (the server loop is :mod:`tmscal.stream`;
docs/streaming.md)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any, TextIO

import click

from .app import INPUT_FILE, TRACKER_PORT_HELP, Finite, handle_errors, main

#: seconds between two status lines when stderr is not a terminal
PLAIN_STATUS_S = 5.0


class _Status:
    """The status line on ``stream`` (stderr): redrawn in place on a terminal (4 times a
    second), one plain line every ``PLAIN_STATUS_S`` seconds elsewhere."""

    def __init__(self, stream: TextIO, tools: list[str]) -> None:
        from .progress import isatty, terminal_width

        self.stream, self.tools = stream, tools
        self.tty = isatty(stream)
        self.width = terminal_width(stream)
        self._last = -1e9

    def text(self, st: Any) -> str:
        from .progress import fit

        rate = f"{st.rate_hz:.1f} Hz" if st.rate_hz else "… Hz"
        client = (("clients " if ", " in st.peer else "client ") + st.peer if st.peer
                  else "no client")
        unseen = [f"{t} unseen {st.unseen[t] / st.frames:.0%}" for t in self.tools
                  if st.frames and st.unseen[t]]
        check = st.crosscheck.last
        probe = ([f"probe vs marker coil {check[0]:.2f} mm {check[1]:.2f}°"] if check
                 else [])
        return fit([f"frames {st.frames}", rate, client, f"sent {st.sent}", *unseen, *probe],
                   self.width - 1)

    def __call__(self, st: Any) -> None:
        now = time.monotonic()
        if now - self._last < (0.25 if self.tty else PLAIN_STATUS_S):
            return
        self._last = now
        line = self.text(st)
        if self.tty:
            self.stream.write(f"\r{line}\x1b[K")
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def finish(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _coil_note(source: str | None, tools: list[str], has_y: bool) -> str:
    """The line that says where the coil comes from (a warning where the marker cannot give
    it), printed once at start on stderr (docs/streaming.md, "Where the coil comes from")."""
    if source == "marker":
        line = ("coil: CoilToTracker = B · X⁻¹ · Y from the marker (the calibration's marker "
                "← coil), CoilToRobotBase from it")
        if "probe" in tools:
            line += ("; the probe, where seen, is sent as ProbeToTracker and cross-checked "
                     "(status: probe vs marker coil)")
        return line
    if source == "probe":
        why = ("the calibration is marker-only (no Y): the coil cannot be derived from the "
               "marker" if not has_y else "no 'marker' tool in tracker.tools")
        return f"warning: {why}; CoilToTracker and CoilToRobotBase from the probe only"
    return ("warning: the calibration is marker-only (no Y) and tracker.tools has no 'probe': "
            "the coil cannot be derived from the marker; CoilToRobotBase and CoilToTracker "
            "are not sent")


def _crosscheck_line(st: Any) -> str | None:
    """The cross-check of a finished stream (probe-measured against marker-derived coil),
    None without a frame that saw both."""
    cc = st.crosscheck
    if not cc.n:
        return None
    return (f"cross-check, probe vs marker-derived coil over {cc.n} frames: mean "
            f"{cc.mean_mm:.3f} mm {cc.mean_deg:.3f}°, max {cc.max_mm:.3f} mm "
            f"{cc.max_deg:.3f}°")


def _check_host(host: str, allow_remote: bool) -> None:
    from ..net import is_loopback

    if is_loopback(host):
        return
    if not allow_remote:
        raise click.BadParameter(
            f"{host!r} is not a loopback address: the stream would be open to the network "
            "(OpenIGTLink has no authentication). Add --allow-remote to serve it anyway.",
            param_hint="--host")
    click.echo(f"warning: serving OpenIGTLink on {host}, reachable from the network without "
               "authentication; anyone who connects sees the live coil pose", err=True)


@main.command()
@click.argument("config", type=INPUT_FILE)
@click.option("--calib", "calib_file", type=INPUT_FILE, required=True,
              help="The calibration to apply: a file written by `tmscal solve -o` (YAML) or "
                   "`tmscal export --format json`. Its Z (robot base ← tracker) maps the "
                   "tracked coil into the robot base.")
@click.option("--port", type=click.IntRange(0, 65535), default=18944, show_default=True,
              help="TCP port of the OpenIGTLink server (18944 is OpenIGTLink's and Slicer's "
                   "default; 0 picks a free port, printed at start).")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on. Loopback (this computer only) unless --allow-remote.")
@click.option("--allow-remote", is_flag=True,
              help="Allow a --host that is not a loopback address (e.g. 0.0.0.0 or the "
                   "navigation computer's network address); prints a warning.")
@click.option("--rate", "rate_hz", type=Finite(0, 1000, lo_open=True), default=None,
              metavar="HZ",
              help="Send at most HZ frames a second (default: every tracker frame).")
@click.option("--max-clients", type=click.IntRange(1, 1000), default=8, show_default=True,
              help="Clients served at once (each with its own queue; a client beyond this is "
                   "closed at once).")
@click.option("--frames", type=click.IntRange(1), default=None,
              help="Stop after this many tracker frames (default: until Ctrl-C).")
@click.option("--tracker-port", default=None, help=TRACKER_PORT_HELP)
@handle_errors
def stream(config: Path, calib_file: Path, port: int, host: str, allow_remote: bool,
           rate_hz: float | None, max_clients: int, frames: int | None,
           tracker_port: str | None) -> None:
    """Stream the tracked coil to 3D Slicer (or any OpenIGTLink client) as live TRANSFORM
    messages, through a stored calibration; the robot is not needed.

    \b
    Device names (Slicer's "FromToTo": the transform maps From into To; 4×4, mm):
      CoilToRobotBase     robot base ← coil centre: Z · coil (the placement rule)
      CoilToTracker       tracker ← coil centre: B · X⁻¹ · Y, from the marker
      ProbeToTracker      tracker ← probe: C as measured
      MarkerToTracker     tracker ← coil marker: B as measured
      TrackerToRobotBase  robot base ← tracker: Z of the calibration

    The coil comes from the marker whenever the config tracks one and the calibration has
    a coil (Y): no probe is needed. The probe, where seen too, is a cross-check: the status
    line shows how far the coil it measures is from the marker's, and the last line its
    mean and maximum. Without a marker tool, or with a marker-only calibration, the coil is
    the probe as measured. A tool that is missing or out of the tracker's volume is not
    sent for that frame, nor the coil derived from it (the client keeps its last pose); the
    status line on stderr counts those frames.

    Several clients are served at once, each with its own limits: a client that reads
    slowly loses its oldest frames (not the others'), one that takes nothing for 10 s is
    disconnected, and so is one that sends a message over 1 MiB.

    In Slicer: OpenIGTLinkIF, add a connector, type Client, this host and port, Active.
    Ctrl-C stops (docs/streaming.md)."""
    from ..acquisition.devices import make_tracker
    from ..config import load_config
    from ..exports import load_calibration
    from ..stream import TRANSFORMS, StreamServer, coil_source, stream_frames
    from .stopping import StopFlag, close_quietly

    _check_host(host, allow_remote)
    cfg = load_config(config)
    cal = load_calibration(calib_file)
    tracker = make_tracker(cfg, tracker_port)
    tools = list(tracker.tools)
    if "marker" not in tools and "probe" not in tools:
        raise click.UsageError(f"{config}: tracker.tools has neither 'marker' nor 'probe'; "
                               "nothing to stream")
    click.echo(_coil_note(coil_source(tools, cal), tools, cal.Y is not None), err=True)
    stop = StopFlag(quiet=True)
    stop.install()
    status = _Status(sys.stderr, tools)
    try:
        server = StreamServer(host, port, max_clients=max_clients)
    except OSError as e:
        raise click.BadParameter(f"cannot listen on {host}:{port}: {e.strerror or e}",
                                 param_hint="--port/--host") from None
    interrupted = False
    try:
        tracker.open()
        server.start()
        click.echo(f"OpenIGTLink server on {server.host}:{server.port}, TRANSFORM "
                   f"{', '.join(TRANSFORMS)} (mm); serving until Ctrl-C")
        sys.stdout.flush()
        st = stream_frames(tracker, cal, server, rate_hz=rate_hz, frames=frames, stop=stop,
                           on_frame=status)
        status.finish()
        click.echo(f"stopped: {st.frames} tracker frames read, {st.sent} sent "
                   f"({st.messages} TRANSFORM messages)")
        check = _crosscheck_line(st)
        if check:
            click.echo(check)
    except KeyboardInterrupt:  # a second Ctrl-C, during a read
        interrupted = True
        status.finish()
        click.echo("stopped", err=True)
    finally:
        server.stop()
        if interrupted:
            close_quietly(tracker)
        else:
            tracker.close()
