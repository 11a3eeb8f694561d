"""The OpenIGTLink tracker's frame and validity rules (``drivers.igtl.frames``) on hand-made
TRANSFORMs: one timestamp is one frame, older transforms are stale, and a tool is usable only
from a valid transform (status OK; without a status, a finite non-identity matrix). Poses are
4×4 mm."""

from __future__ import annotations

import numpy as np
import pytest

from tmscal.drivers.igtl.frames import FrameAssembler, tool_state
from tmscal.drivers.igtl.wire import Transform
from tmscal.geometry import make_pose

TOOLS = {"marker": "MarkerToTracker", "probe": "ProbeToTracker"}
POSE = make_pose(np.eye(3), [10.0, -20.0, -1500.0])


def tf(device: str, stamp: int, matrix: np.ndarray = POSE, **meta: str) -> Transform:
    return Transform(device, stamp, stamp / 2**32, np.array(matrix, dtype=float), meta,
                     2 if meta else 1)


def test_a_frame_is_delivered_when_every_tool_of_its_timestamp_has_come() -> None:
    a = FrameAssembler(TOOLS)
    assert a.feed(tf("MarkerToTracker", 10), 1.0) == []
    (fr,) = a.feed(tf("ProbeToTracker", 10), 1.5)
    assert fr.frame == 0 and fr.host_time == 1.5
    assert fr.tools["marker"].usable and fr.tools["probe"].usable
    np.testing.assert_array_equal(fr.pose("marker"), POSE)


def test_a_frame_missing_a_tool_is_delivered_when_the_next_one_starts() -> None:
    a = FrameAssembler(TOOLS)
    assert a.feed(tf("MarkerToTracker", 10), 1.0) == []
    (fr,) = a.feed(tf("MarkerToTracker", 11), 2.0)
    assert fr.frame == 0 and fr.tools["probe"].missing and fr.tools["marker"].usable


def test_an_older_transform_is_stale_and_not_part_of_the_frame() -> None:
    a = FrameAssembler(TOOLS)
    a.feed(tf("MarkerToTracker", 10), 1.0)
    a.feed(tf("ProbeToTracker", 10), 1.0)
    assert a.feed(tf("MarkerToTracker", 11), 2.0) == []
    assert a.feed(tf("ProbeToTracker", 10), 2.0) == []    # the probe's old transform again
    (fr,) = a.feed(tf("MarkerToTracker", 12), 3.0)
    assert fr.frame == 1 and fr.tools["probe"].missing and a.stale == 1


def test_other_devices_mark_frames_but_are_not_tools() -> None:
    a = FrameAssembler(TOOLS)
    a.feed(tf("ReferenceToTracker", 10), 1.0)
    (fr,) = a.feed(tf("ReferenceToTracker", 11), 2.0)
    assert fr.tools["marker"].missing and fr.tools["probe"].missing
    assert set(fr.tools) == set(TOOLS)


def test_late_parts_of_a_delivered_frame_are_ignored() -> None:
    a = FrameAssembler(TOOLS)
    a.feed(tf("MarkerToTracker", 10), 1.0)
    a.feed(tf("ProbeToTracker", 10), 1.0)
    assert a.feed(tf("ReferenceToTracker", 10), 1.1) == []
    assert a.feed(tf("MarkerToTracker", 10), 1.2) == []
    assert a.feed(tf("MarkerToTracker", 11), 2.0) == []   # frame 1 opens, not frame 0 again
    assert a.next_frame == 1


def test_frame_numbers_start_where_asked() -> None:
    a = FrameAssembler(TOOLS, first_frame=41)
    a.feed(tf("MarkerToTracker", 10), 1.0)
    (fr,) = a.feed(tf("ProbeToTracker", 10), 1.0)
    assert fr.frame == 41


def test_two_tools_with_one_device_name_are_refused() -> None:
    with pytest.raises(ValueError, match="share one device name"):
        FrameAssembler({"marker": "A", "probe": "A"})


@pytest.mark.parametrize("matrix, meta, usable, oov", [
    (POSE, {}, True, False),
    (np.eye(4), {}, False, False),                          # PlusServer's invalid, version 1
    (POSE, {"TransformStatus": "OK"}, True, False),
    (np.eye(4), {"TransformStatus": "OK"}, True, False),    # the status is believed
    (POSE, {"TransformStatus": "ok "}, True, False),
    (POSE, {"TransformStatus": "MISSING"}, False, False),   # the status is believed
    (POSE, {"TransformStatus": "OUT_OF_VIEW"}, False, False),
    (np.eye(4), {"TransformStatus": "OUT_OF_VOLUME"}, False, True),
    (POSE, {"TransformStatus": "INVALID"}, False, False),
    (POSE, {"TransformStatus": "SWITCH1_IS_ON"}, False, False),
    (np.full((4, 4), np.nan), {}, False, False),
    (np.where(np.eye(4) == 1, np.inf, POSE), {"TransformStatus": "OK"}, False, False),
])
def test_validity_rule(matrix, meta, usable: bool, oov: bool) -> None:
    st = tool_state(tf("MarkerToTracker", 1, matrix, **meta))
    assert st.usable is usable and st.missing is (not usable)
    assert st.out_of_volume is oov
    assert (st.pose is not None) is usable
