"""Stopping a command that runs devices: the Ctrl-C / SIGTERM flag of ``acquire``, ``track``,
``stream`` and ``selfcal acquire``, and the quiet close of a device whose link a second
Ctrl-C interrupted."""

from __future__ import annotations

from typing import Any

import click


class StopFlag:
    """First SIGINT/SIGTERM sets the flag (finish the pose in flight); a second SIGINT raises
    KeyboardInterrupt."""

    def __init__(self, quiet: bool = False) -> None:
        self.set = False
        self.quiet = quiet

    def __call__(self) -> bool:
        return self.set

    def install(self) -> None:
        import signal

        def handler(signum: int, frame: Any) -> None:
            if self.set and signum == signal.SIGINT:
                raise KeyboardInterrupt
            self.set = True
            if not self.quiet:
                click.echo("\nstopping after the pose in flight (Ctrl-C again to abort now)",
                           err=True)

        signal.signal(signal.SIGINT, handler)
        signal.signal(signal.SIGTERM, handler)


def close_quietly(dev: Any) -> None:
    """Close a device whose link was interrupted mid-reply: its stop command may meet the
    rest of that reply, so the drivers' warnings and errors are held back."""
    import logging

    drivers = logging.getLogger("tmscal.drivers")
    level = drivers.level
    drivers.setLevel(logging.CRITICAL)
    try:
        dev.close()
    except Exception:  # the process is ending on the user's request
        pass
    finally:
        drivers.setLevel(level)
