"""What the user sees while devices run: the acquisition progress display and the capture of
device libraries' stderr into the log (the live tool table of ``tmscal track`` is
:mod:`tmscal.cli.track_table`).

The progress display uses tqdm, already a dependency of tmscal: its bar, rate and ETA
arithmetic (also on a resumed run, from ``initial``), its multi-line positions and its
``logging_redirect_tqdm`` (log lines printed above the bar, not through it) are all we need;
rich would add a dependency for the same three lines. On a terminal it shows three lines,
refreshed in place::

    pose 123/500 |██████████▌                    | 25% ETA 02:31 sampling
    marker spread 0.045 mm / 0.094°   probe spread 0.051 mm / 0.102°
    skipped 3; last: probe seen in 58 of 100 frames, below min_share 0.8

and a skipped pose's whole reason is written above them. Elsewhere (a pipe, a log file) it
prints one plain line per pose, without carriage returns. Every line fits the terminal's
width (80 columns off a terminal; fields that do not fit are dropped from the end) but the
line of a skipped pose, which carries its whole reason. Spreads are the RMS distance (mm) and
RMS angle (deg) of a pose's samples about their mean (``tmscal.acquisition.sample.spread_of``).
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import shutil
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, TextIO

from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from ..acquisition.progress import Progress
from ..escape import visible

__all__ = ["AcquireProgress", "FitBar", "with_fit_bar", "fit", "spread_text", "stderr_to_log",
           "isatty", "terminal_width"]

PLAIN_WIDTH = 80
_SEP = "  "


def fit(fields: list[str], width: int, cut: bool = False) -> str:
    """``fields`` joined by two spaces, leaving out trailing fields that would make the line
    longer than ``width``; with ``cut`` the first field that does not fit is shortened with
    "…" instead (if 12 or more columns are left for it). The first field is always shown,
    shortened if need be."""
    line = _cut(fields[0], width)
    for f in fields[1:]:
        room = width - len(line) - len(_SEP)
        if len(f) > room:
            if cut and room >= 12:
                line += _SEP + _cut(f, room)
            break
        line += _SEP + f
    return line


def _cut(text: str, width: int) -> str:
    return text if len(text) <= width else text[:max(0, width - 1)] + "…"


def spread_text(rec: Any) -> list[str]:
    """One "<body> spread <mm> mm / <deg>°" per tracked body of a pose record."""
    out = []
    for body in ("marker", "probe"):
        sp = (rec.spread or {}).get(body)
        if sp:
            out.append(f"{body} spread {sp['trans_mm']:.3f} mm / {sp['rot_deg']:.3f}°")
    return out


def _short_reason(reason: str) -> str:
    """A skip reason without its parenthesised explanations (kept in the session)."""
    parts = [p.split(" (", 1)[0].strip() for p in reason.split(";")]
    return "; ".join(p for p in parts if p)


def terminal_width(stream: TextIO) -> int:
    """Columns to fill on ``stream``: the terminal's (at least 40), 80 off a terminal."""
    if not isatty(stream):
        return PLAIN_WIDTH
    return max(40, shutil.get_terminal_size((PLAIN_WIDTH, 24)).columns)


def isatty(stream: TextIO) -> bool:
    """True when ``stream`` is a terminal (False for a closed or file-less stream)."""
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


class AcquireProgress(Progress):
    """Progress of an acquisition on ``stream``, a ``tmscal.acquisition.progress.Progress``:
    it shows ``started``, ``phase`` and ``pose``; ``close`` at the end. ``tty`` None decides
    from the stream; ``label`` names one pose ("pose", "configuration")."""

    def __init__(self, stream: TextIO, tty: bool | None = None, label: str = "pose") -> None:
        self.stream = stream
        self.tty = isatty(stream) if tty is None else tty
        self.width = terminal_width(stream) if tty is None else (
            max(40, shutil.get_terminal_size((PLAIN_WIDTH, 24)).columns) if tty
            else PLAIN_WIDTH)
        self.label = label
        self.skipped = 0
        self.last_reason: str | None = None
        self._bars: list[Any] = []
        self._t0 = time.monotonic()
        self._first = 0
        self._redirect: Any = None

    def __enter__(self) -> AcquireProgress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def started(self, done: int, total: int, skipped: int = 0) -> None:
        """The plan is known: ``done`` of ``total`` poses already in the session, ``skipped``
        of them skipped."""
        self.skipped, self._first, self._t0 = skipped, done, time.monotonic()
        self.total = total
        if not self.tty:
            return
        common = dict(file=self.stream, ncols=self.width, dynamic_ncols=False, mininterval=0.1)
        main = tqdm(total=total, initial=done, position=0, leave=True,
                    bar_format=self.label + " {n_fmt}/{total_fmt} |{bar}| "
                                            "{percentage:3.0f}% ETA {remaining} {desc}",
                    **common)
        status = [tqdm(total=0, position=k, leave=False, bar_format="{desc}", **common)
                  for k in (1, 2)]
        self._bars = [main, *status]
        self._redirect = logging_redirect_tqdm()
        self._redirect.__enter__()
        self._status()

    def phase(self, i: int, name: str) -> None:
        """Pose ``i`` (0-based plan index) is now ``name`` (moving, settling, sampling)."""
        if self._bars:
            self._bars[0].set_description_str(name, refresh=True)

    def pose(self, done: int, total: int, rec: Any) -> None:
        """Pose ``rec`` was saved; ``done`` of ``total`` are now in the session."""
        if rec.skipped:
            self.skipped += 1
            self.last_reason = _short_reason(rec.skipped)
        if self._bars:
            if rec.skipped:  # the whole reason, above the bars (the status line is cut)
                tqdm.write(f"{self.label} {done}/{total} skipped: {visible(rec.skipped)}",
                           file=self.stream)
            self._bars[0].set_description_str("", refresh=False)
            self._bars[0].update(done - self._bars[0].n)
            self._status(rec)
            return
        fields = [f"{self.label} {done}/{total}", f"ETA {self._eta(done, total)}"]
        if rec.skipped:  # the whole reason: the line may be longer than the width
            print(_SEP.join(fields + [f"skipped ({self.skipped} so far): "
                                      f"{visible(rec.skipped)}"]), file=self.stream, flush=True)
            return
        fields += [f"skipped {self.skipped}", *spread_text(rec)]
        print(fit(fields, self.width), file=self.stream, flush=True)

    def _status(self, rec: Any = None) -> None:
        spread = spread_text(rec) if rec is not None and not rec.skipped else []
        skipped = f"skipped {self.skipped}"
        if self.last_reason:
            skipped += f"; last: {self.last_reason}"
        for bar, text in zip(self._bars[1:], (fit(spread or [" "], self.width),
                                              _cut(skipped, self.width))):
            if spread or bar is self._bars[2]:
                bar.set_description_str(text, refresh=True)

    def _eta(self, done: int, total: int) -> str:
        new = done - self._first
        if new <= 0:
            return "?"
        left = (time.monotonic() - self._t0) / new * (total - done)
        return tqdm.format_interval(left)

    def close(self) -> None:
        """Leave the bar's last state on screen and the terminal's cursor below it."""
        if self._redirect is not None:
            self._redirect.__exit__(None, None, None)
            self._redirect = None
        for bar in reversed(self._bars):
            bar.close()
        self._bars = []


class FitBar:
    """A long fit's progress bar on stderr: called as ``progress(done, total, what)`` (fits
    done of ``total``, the one running and its iteration; the kinematic estimate's
    :data:`tmscal.calib.kinematics.estimate.Progress`, ``solving.solve``'s ``progress``). The
    tqdm bar appears at the first call, only on a terminal (tqdm's ``disable=None``), and is
    removed by :meth:`close`, e.g.::

        solve 7/23 fits |███      | 30% [00:04<00:09] kinematics: full, fold 2/5: LM iteration 3
    """

    def __init__(self, desc: str = "solve", stream: TextIO | None = None) -> None:
        self.desc, self.stream = desc, stream
        self._bar: Any = None

    def __call__(self, done: int, total: int, what: str) -> None:
        if self._bar is None:
            label = self.desc.replace("{", "{{").replace("}", "}}")
            self._bar = tqdm(total=total, unit="fit", disable=None, file=self.stream or sys.stderr,
                             leave=False, dynamic_ncols=True,
                             bar_format=label + " {n_fmt}/{total_fmt} fits |{bar}| "
                                                "{percentage:3.0f}% [{elapsed}<{remaining}] {desc}")
        bar = self._bar
        if bar.disable:
            return
        bar.total, bar.n = total, done
        bar.set_description_str(what, refresh=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


def with_fit_bar(fn: Callable[..., Any], desc: str = "solve") -> Callable[..., Any]:
    """``fn`` called with ``progress=`` a :class:`FitBar`, closed when it returns or raises
    (before the CLI prints an error)."""
    @functools.wraps(fn)
    def run(*args: Any, **kwargs: Any) -> Any:
        bar = FitBar(desc)
        try:
            return fn(*args, progress=bar, **kwargs)
        finally:
            bar.close()
    return run


@contextlib.contextmanager
def stderr_to_log(logger: logging.Logger | None = None) -> Iterator[None]:
    """While devices run, file descriptor 2 goes to a pipe; a thread logs each line written
    to it (``logger``, default ``tmscal.devices.stderr``, level WARNING). Device libraries
    that print from C or C++ (ur_rtde) or child processes then cannot tear the progress bar.
    Python's own ``sys.stderr`` (and log handlers writing to it) is pointed at the original
    stderr meanwhile, so that nothing loops through the pipe. Everything is restored after."""
    logger = logger or logging.getLogger("tmscal.devices.stderr")
    old = sys.stderr
    with contextlib.suppress(Exception):
        old.flush()
    saved = os.dup(2)
    r, w = os.pipe()
    new = open(os.dup(saved), "w", buffering=1, encoding=getattr(old, "encoding", None),
               errors="backslashreplace")
    moved = _repoint_handlers(old, new)
    reader = threading.Thread(target=_log_lines, args=(r, logger), daemon=True,
                              name="stderr-to-log")
    reader.start()
    os.dup2(w, 2)
    os.close(w)
    sys.stderr = new
    try:
        yield
    finally:
        with contextlib.suppress(Exception):
            new.flush()
        os.dup2(saved, 2)  # the pipe's last write end closes: the reader sees EOF
        os.close(saved)
        reader.join(timeout=5.0)  # a hang guard only (a child still holding the pipe)
        sys.stderr = old
        for h in moved:
            h.setStream(old)
        new.close()


def _repoint_handlers(old: Any, new: Any) -> list[logging.StreamHandler[Any]]:
    """Point every logging StreamHandler writing to ``old`` at ``new``; return them."""
    loggers = [logging.getLogger(), *(lg for lg in logging.Logger.manager.loggerDict.values()
                                      if isinstance(lg, logging.Logger))]
    moved = []
    for lg in loggers:
        for h in lg.handlers:
            if isinstance(h, logging.StreamHandler) and h.stream is old:
                h.setStream(new)
                moved.append(h)
    return moved


def _log_lines(fd: int, logger: logging.Logger) -> None:
    """Log each line read from ``fd`` until EOF, then close it."""
    buf = b""
    try:
        while chunk := os.read(fd, 4096):
            buf += chunk
            *lines, buf = buf.split(b"\n")
            for line in lines:
                _log_one(logger, line)
        if buf:
            _log_one(logger, buf)
    finally:
        os.close(fd)


def _log_one(logger: logging.Logger, line: bytes) -> None:
    text = line.decode("utf-8", "backslashreplace").rstrip()
    if text:
        logger.warning("%s", text)
