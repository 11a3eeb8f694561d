"""``tmscal mock``: serve the mock devices of a rig config."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from .app import INPUT_FILE, handle_errors, main


@main.command()
@click.argument("config", type=INPUT_FILE)
@click.option("--transport", type=click.Choice(["config", "pty", "tcp"]), default="config",
              show_default=True,
              help="Tracker transport: config = TCP at the config's tracker address when it "
                   "is a host and port (else a pty); pty = a new /dev/pts; tcp = an "
                   "ephemeral loopback port. A tracker that speaks TCP only (igtl) is served "
                   "on TCP.")
@click.option("--json", "as_json", is_flag=True,
              help='Print the endpoints as one JSON object on the first line, e.g. '
                   '{"tracker": "/dev/pts/7", "robot": "127.0.0.2"}.')
@handle_errors
def mock(config: Path, transport: str, as_json: bool) -> None:
    """Serve the mock devices of a rig config (one shared sim rig) until Ctrl-C / SIGTERM."""
    import signal
    import threading

    from ..config import load_config
    from ..mocks.launch import start_mock_rig

    cfg = load_config(config)
    done = threading.Event()
    signal.signal(signal.SIGINT, lambda *a: done.set())
    signal.signal(signal.SIGTERM, lambda *a: done.set())
    with start_mock_rig(cfg, tracker_transport=transport) as mr:
        if as_json:
            click.echo(json.dumps(mr.endpoints), nl=True)
        else:
            for k, v in mr.endpoints.items():
                click.echo(f"{k:<8} {v}")
            click.echo("serving; Ctrl-C to stop")
        sys.stdout.flush()
        while not done.wait(0.2):
            pass
