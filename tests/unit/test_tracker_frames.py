"""``Tracker.distinct_frames``: each frame number once, bounded by reads, time and stalls."""

from __future__ import annotations

import itertools

import pytest

from tmscal.drivers.base import DeviceTimeout, ToolState, Tracker, TrackerFrame


class Scripted(Tracker):
    """A tracker whose ``read()`` returns the given frame numbers in turn (then the last one)."""

    name = "scripted"

    def __init__(self, numbers):
        super().__init__(["marker"], 60.0)
        self._numbers = iter(numbers)
        self._last = 0
        self.reads = 0

    def _open(self): ...
    def _close(self): ...

    def _read(self):
        self.reads += 1
        self._last = next(self._numbers, self._last)
        return TrackerFrame(self._last, 0.0, {"marker": ToolState(None, missing=True)})


def test_repeats_are_skipped_and_limit_stops_reading():
    with Scripted([1, 1, 2, 2, 2, 3, 1, 4, 5]) as tr:
        got = [f.frame for f in tr.distinct_frames(4)]
        assert got == [1, 2, 3, 4]
        assert tr.reads == 8  # nothing read after the fourth distinct frame


def test_unbounded_until_the_caller_stops():
    with Scripted(itertools.count()) as tr:
        assert [f.frame for f in itertools.islice(tr.distinct_frames(), 5)] == [0, 1, 2, 3, 4]


def test_read_bound_names_the_distinct_count():
    with Scripted([7, 8]) as tr, pytest.raises(
            DeviceTimeout, match=r"scripted: tracker delivered only 2 distinct frames of 5 in "
                                 r"10 reads \(read limit"):
        list(tr.distinct_frames(5, max_reads=10))


@pytest.mark.parametrize("bound", ["timeout_s", "stall_s"])
def test_time_bounds(bound):
    with Scripted([1]) as tr, pytest.raises(DeviceTimeout, match=r"only 1 distinct frames "
                                                                 r"of 3 in 1 reads"):
        list(tr.distinct_frames(3, **{bound: 0.0}))  # expired at once: no waiting in tests


def test_stall_restarts_on_each_new_frame():
    with Scripted(range(100)) as tr:
        # a new frame on every read: the stall bound (far from 0) never trips
        assert len(list(tr.distinct_frames(100, stall_s=60.0))) == 100
