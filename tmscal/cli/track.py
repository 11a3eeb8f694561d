"""``tmscal track``: the tracker's tools and a live table of their poses (the table itself is
:mod:`tmscal.cli.track_table`)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ..escape import value_text
from .app import INPUT_FILE, TRACKER_PORT_HELP, handle_errors, main, old_spelling
from .stopping import StopFlag, close_quietly


@main.command()
@click.argument("config", type=INPUT_FILE)
@click.option("--tracker-port", default=None, help=TRACKER_PORT_HELP)
@click.option("--port", "old_port", default=None, hidden=True)
@click.option("--frames", type=click.IntRange(1), default=None,
              help="Stop after this many distinct frames (default: until Ctrl-C).")
@click.option("--plain", is_flag=True,
              help="Print every frame's lines one after another instead of a table redrawn "
                   "in place (the default off a terminal).")
@handle_errors
def track(config: Path, tracker_port: str | None, old_port: str | None, frames: int | None,
          plain: bool) -> None:
    """Connect to the tracker, list the tools and show a live table: per tool whether it is
    seen, its position (mm) and rotation (rotation vector, deg) in the tracker frame, the
    tracker's RMS fit error (mm), volume flags, and the tracker's frame rate (Hz).

    Ctrl-C stops after the frame being read and closes the tracker; a second Ctrl-C
    abandons the read in flight."""
    from ..acquisition.devices import make_tracker
    from ..config import load_config
    from .track_table import TrackView

    port = old_spelling(tracker_port, old_port, "--tracker-port", "--port")
    cfg = load_config(config)
    stop = StopFlag(quiet=True)
    stop.install()
    tr = make_tracker(cfg, port)
    tr.open()
    interrupted = False
    try:
        ident = tr.identity()
        click.echo("tracker: " + ", ".join(f"{k} {value_text(v)}" for k, v in ident.items()
                                           if v))
        handles = getattr(tr, "handles", {})  # an NDI's port handles
        tools = ident.get("tools")
        names = tools if isinstance(tools, dict) else {}
        for name in tr.tools:
            h = handles.get(name)
            if h is None and name in names:  # what the driver knows it by (a TRANSFORM name)
                click.echo(f"  tool {name:<8} device {names[name]}")
            else:
                click.echo(f"  tool {name:<8} handle {h if h is not None else '?'}")
        view = TrackView(sys.stdout, plain=plain)
        view.header()
        frames_in = tr.distinct_frames(frames, stall_s=5.0)
        for fr in frames_in:
            view.show(fr)
            if stop():
                break
        frames_in.close()
        view.finish()
    except KeyboardInterrupt:  # a second Ctrl-C, during a read: the link's state is unknown
        interrupted = True
    finally:
        if interrupted:
            close_quietly(tr)
        else:
            tr.close()
