"""The live tool table of ``tmscal track``: one row per tool (seen, position mm and rotation
vector deg in the tracker frame, the tracker's RMS fit error mm, volume flags) under the
tracker's frame rate (Hz), redrawn in place on a terminal, appended elsewhere."""

from __future__ import annotations

import time
from collections import deque
from typing import Any, TextIO

import numpy as np

from .progress import PLAIN_WIDTH, fit, isatty, terminal_width

__all__ = ["TRACK_LEGEND", "TrackView", "track_rows"]


TRACK_LEGEND = ("position: tracker_from_tool origin, mm; rotation: rotation vector "
                "(axis × angle) in deg, tracker frame; rms: the tracker's fit error, mm; "
                "flags: OUT = out of volume, PART = partly out of volume")
_TRACK_HEAD = (f"  {'tool':<8} {'seen':<4} {'x mm':>8} {'y mm':>8} {'z mm':>9} "
               f"{'rot x°':>7} {'rot y°':>7} {'rot z°':>7} {'rms mm':>6} flags")


def track_rows(frame: Any, rate_hz: float | None) -> list[str]:
    """The lines of one tracker frame: "frame N, R Hz", then one row per tool under
    ``_TRACK_HEAD`` (a missing tool shows "no" and blanks)."""
    from ..geometry import rotvec_from_matrix
    rate = f"{rate_hz:.1f} Hz" if rate_hz else "… Hz"
    lines = [f"frame {frame.frame}   tracker frame rate {rate}"]
    for name, st in frame.tools.items():
        if st.pose is None:
            lines.append(f"  {name:<8} {'no':<4}")
            continue
        t = st.pose[:3, 3]
        rv = np.degrees(rotvec_from_matrix(st.pose[:3, :3]))
        flags = " ".join(f for f, on in (("OUT", st.out_of_volume),
                                          ("PART", st.partially_out_of_volume)) if on)
        rms = f"{st.error_mm:6.3f}" if st.error_mm is not None else f"{'-':>6}"
        lines.append(f"  {name[:8]:<8} {'yes':<4} {t[0]:8.2f} {t[1]:8.2f} {t[2]:9.2f} "
                     f"{rv[0]:7.2f} {rv[1]:7.2f} {rv[2]:7.2f} {rms} {flags}".rstrip())
    return lines


class TrackView:
    """``tmscal track``'s output on ``stream``: on a terminal (unless ``plain``) one table
    redrawn in place, at most ``redraw_hz`` times a second; else every frame's lines
    appended. ``frame_rate`` is measured from the device's frame numbers over the last
    second of host time."""

    def __init__(self, stream: TextIO, plain: bool = False, redraw_hz: float = 10.0) -> None:
        self.stream = stream
        self.plain = plain or not isatty(stream)
        self.width = terminal_width(stream) if not self.plain else PLAIN_WIDTH
        self._period = 1.0 / redraw_hz
        self._drawn = 0
        self._last_draw = -1e9
        self._recent: deque[tuple[float, int]] = deque()
        self._pending: list[str] | None = None

    def header(self) -> None:
        """The legend and the column heads (once)."""
        for line in _wrap(TRACK_LEGEND, self.width) + [_TRACK_HEAD]:
            print(line, file=self.stream)
        self.stream.flush()

    def frame_rate(self, frame: Any) -> float | None:
        """Frames per second by the device's frame counter over the last second (None
        until two frames a measurable time apart have arrived)."""
        self._recent.append((frame.host_time, frame.frame))
        while len(self._recent) > 2 and frame.host_time - self._recent[0][0] > 1.0:
            self._recent.popleft()
        (t0, f0), (t1, f1) = self._recent[0], self._recent[-1]
        return (f1 - f0) / (t1 - t0) if t1 > t0 and f1 > f0 else None

    def show(self, frame: Any) -> None:
        """Print (plain) or redraw (terminal) ``frame``."""
        lines = [fit([ln], self.width) for ln in track_rows(frame, self.frame_rate(frame))]
        if self.plain:
            print("\n".join(lines), file=self.stream, flush=True)
            return
        self._pending = lines
        now = time.monotonic()
        if now - self._last_draw >= self._period:
            self._last_draw = now
            self._draw()

    def finish(self) -> None:
        """Draw the last frame if the redraw limit held it back."""
        if not self.plain and self._pending:
            self._draw()

    def _draw(self) -> None:
        lines, self._pending = self._pending or [], None
        up = f"\x1b[{self._drawn}A" if self._drawn else ""
        self.stream.write(up + "".join(f"\r{ln}\x1b[K\n" for ln in lines))
        self.stream.flush()
        self._drawn = len(lines)


def _wrap(text: str, width: int) -> list[str]:
    import textwrap
    return textwrap.wrap(text, width)
