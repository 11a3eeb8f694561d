"""Watching the skipped poses of a run: a share of skips above ``run.warn_skip_share`` over
the last ``run.skip_window`` poses warns once (until the share falls back), a share above
``run.stop_skip_share`` stops the run, which the session leaves resumable. Both messages name
the commonest reason, e.g. "probe not seen (missing or out of volume) in 12 of the last 20
poses", or for tools seen in some frames but too few "marker and probe seen in too few frames
(below min_share 0.9) in 3 of the last 3 poses (the last: marker 68 of 100 frames, probe 63 of
100)"; when the window holds skips of other causes too, or the session holds more (earlier
windows, a resumed run's first part), they add both counts: "(11 skipped in the window, 14 in
the session)". Shares are of the window's full length, so the first skips of a run count as
much as later ones and a single early skip does not read as 100 %.
"""

from __future__ import annotations

from collections import Counter, deque

from ..config import RunConfig
from ..session import PoseRecord, seen_counts, seen_text, skip_cause

__all__ = ["SkipWatch"]

class SkipWatch:
    """Feed it every pose record of a run (``add``); it says when to warn and when to stop."""

    def __init__(self, run: RunConfig, skipped_before: int = 0) -> None:
        """``skipped_before``: the skipped poses the session already holds (a resumed run)."""
        self.session_skipped = skipped_before
        self.window = run.skip_window
        self.warn_share = run.warn_skip_share
        self.stop_share = run.stop_skip_share
        self._last: deque[str | None] = deque(maxlen=self.window)
        self._latest: dict[str, str] = {}  # cause → the last reason of that cause
        self._warned = False

    def add(self, rec: PoseRecord) -> tuple[str | None, str | None]:
        """(warning, stop reason) after pose ``rec``: each None or one line naming the
        commonest cause of the skips in the window and how many poses it hit."""
        self._last.append(skip_cause(rec.skipped) if rec.skipped else None)
        if rec.skipped:
            self._latest[skip_cause(rec.skipped)] = rec.skipped
        self.session_skipped += rec.skipped is not None
        causes = Counter(c for c in self._last if c is not None)
        k = sum(causes.values())
        if k == 0:
            self._warned = False
            return None, None
        cause, n = causes.most_common(1)[0]
        what = f"{cause} in {n} of the last {len(self._last)} poses"
        last = self._latest.get(cause, "")
        if any(k_seen for _, k_seen, _, _ in seen_counts(last)):  # seen, but in too few
            what += f" (the last: {seen_text(last)})"
        if n != k or self.session_skipped != k:
            what += f" ({k} skipped in the window, {self.session_skipped} in the session)"
        if k > self.stop_share * self.window:
            return None, f"{what}, above run.stop_skip_share {self.stop_share:g}"
        if k > self.warn_share * self.window:
            if self._warned:
                return None, None
            self._warned = True
            return (f"{what}, above run.warn_skip_share {self.warn_share:g}; check the "
                    "tools' line of sight"), None
        self._warned = False
        return None, None
