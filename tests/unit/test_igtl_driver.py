"""The OpenIGTLink tracker driver against the OpenIGTLink tracker mock over real loopback
sockets (port 0): poses equal the sim rig's truth within the noise, frame numbers increase,
dropped, stale, unseen and out-of-volume tools are missing, and every failure is its typed
error naming host:port. Poses are tracker_from_<body>, 4×4 mm."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest

from tests.rigs import free_port, unique_host
from tmscal.drivers.igtl.tracker import IGTLTracker
from tmscal.errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError
from tmscal.geometry import rotation_angle
from tmscal.mocks.clock import FAST, REAL_TIME
from tmscal.mocks.igtl import IGTLFaults, IGTLTrackerMock, MeasurementVolume
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

TOOLS = {"marker": "MarkerToTracker", "probe": "ProbeToTracker"}
SIGMA_MM = 0.05
POS_TOL_MM = 0.5   # ≫ the pose noise of 4 spheres at σ = 0.05 mm, ≪ anything wrong
ROT_TOL_RAD = np.radians(0.5)


def _rig(sigma_mm: float = SIGMA_MM) -> SimRig:
    return SimRig(tms_rig_truth(), noise=Noise(fiducial_sigma_mm=sigma_mm),
                  rng=np.random.default_rng(3), start=TMS_RIG_P0)


@contextmanager
def served(rig: SimRig | None = None, clock=FAST, **kw: Any) -> Iterator[IGTLTrackerMock]:
    m = IGTLTrackerMock(rig or _rig(), TOOLS, port=0, clock=clock, **kw)
    m.start()
    try:
        yield m
    finally:
        m.close()


def tracker(m: IGTLTrackerMock, **kw: Any) -> IGTLTracker:
    kw.setdefault("timeout_s", 2.0)
    return IGTLTracker("127.0.0.1", TOOLS, port=m.port, **kw)


@pytest.mark.parametrize("clock", [FAST, REAL_TIME], ids=["fast", "real"])
def test_poses_are_the_rigs_truth_within_the_noise(clock) -> None:
    rig = _rig()
    with served(rig, clock=clock) as m, tracker(m) as t:
        frames = list(t.distinct_frames(20, timeout_s=30))
    for body in TOOLS:
        true = rig.true_body(body)
        for fr in frames:
            st = fr.tools[body]
            assert st.usable and not st.missing
            assert np.linalg.norm(st.pose[:3, 3] - true[:3, 3]) < POS_TOL_MM
            assert rotation_angle(true[:3, :3].T @ st.pose[:3, :3]) < ROT_TOL_RAD
    # noise makes consecutive frames differ: each frame is a new observation
    assert not np.array_equal(frames[0].pose("marker"), frames[1].pose("marker"))


def test_frame_numbers_increase_and_host_times_do_not_go_back() -> None:
    with served() as m, tracker(m) as t:
        frames = list(t.distinct_frames(200, timeout_s=30))
    numbers = [f.frame for f in frames]
    assert all(b > a for a, b in zip(numbers, numbers[1:]))
    times = [f.host_time for f in frames]
    assert all(b >= a for a, b in zip(times, times[1:]))


def test_read_waits_for_a_new_frame_instead_of_repeating_one() -> None:
    with served() as m, tracker(m) as t:
        numbers = [t.read().frame for _ in range(30)]
    assert len(set(numbers)) == 30


def test_identity_tells_what_the_source_sent_and_survives_a_reconnect() -> None:
    with served(faults=IGTLFaults(extra_messages=True)) as m, tracker(m) as t:
        list(t.distinct_frames(5, timeout_s=10))
        ident = t.identity()
        received = t.received()
        t.close()
        t.open()
        again = t.identity()
    assert ident == {"driver": "igtl", "host": "127.0.0.1", "port": m.port, "tools": TOOLS,
                     # the driver's version-2 GET_STATUS made the mock answer in version 2
                     "header_version": 2, "transform_status": True}
    assert again == ident
    assert received["STATUS"] >= 5 and received["STRING"] >= 5 and received["TRANSFORM"] >= 10


def test_without_asking_for_metadata_a_source_answers_in_version_1() -> None:
    rig = _rig()
    with served(rig) as m, tracker(m, ask_metadata=False) as t:
        fr = next(iter(t.distinct_frames(1, timeout_s=10)))
        ident = t.identity()
    assert ident["header_version"] == 1 and not ident["transform_status"]
    assert np.linalg.norm(fr.pose("probe")[:3, 3] - rig.true_body("probe")[:3, 3]) \
        < POS_TOL_MM


def test_a_dropped_tool_is_missing_in_every_frame() -> None:
    with served(faults=IGTLFaults(drop_tools=("probe",))) as m, tracker(m) as t:
        frames = list(t.distinct_frames(20, timeout_s=30))
    for fr in frames:
        assert fr.tools["probe"].missing and fr.pose("probe") is None
        assert not fr.tools["probe"].usable
        assert fr.tools["marker"].usable


def test_a_stale_tool_is_missing_once_its_transform_is_older_than_the_frame() -> None:
    with served(faults=IGTLFaults(stale_tools=("probe",))) as m, tracker(m) as t:
        frames = list(t.distinct_frames(20, timeout_s=30))
    later = [f for f in frames if f.frame > 0]   # frame 0 holds the probe's only fresh pose
    assert len(later) >= 19
    assert all(f.tools["probe"].missing and f.tools["marker"].usable for f in later)


@pytest.mark.parametrize("ask_metadata", [True, False], ids=["TransformStatus", "identity"])
def test_unseen_tools_sent_as_invalid_are_missing(ask_metadata: bool) -> None:
    """PlusServer with SendValidTransformsOnly FALSE sends an unseen tool as the identity:
    version 2 with TransformStatus MISSING, version 1 without a status (the identity rule)."""
    faults = IGTLFaults(missing_fraction=1.0)
    with served(faults=faults, send_invalid=True) as m, \
            tracker(m, ask_metadata=ask_metadata) as t:
        frames = list(t.distinct_frames(10, timeout_s=30))
        version = t.identity()["header_version"]
    assert version == (2 if ask_metadata else 1)
    for fr in frames:
        for body in TOOLS:
            assert fr.tools[body].missing and fr.pose(body) is None


def test_a_tool_out_of_the_volume_is_missing_and_out_of_volume() -> None:
    far_away = MeasurementVolume(z_near_mm=-10.0, z_far_mm=-20.0)   # the rig is at -1.5 m
    with served(volume=far_away, send_invalid=True) as m, tracker(m) as t:
        fr = next(iter(t.distinct_frames(1, timeout_s=10)))
    for body in TOOLS:
        assert fr.tools[body].missing and fr.tools[body].out_of_volume
        assert fr.pose(body) is None


def test_some_frames_missing_a_tool_are_skipped_samples_not_errors() -> None:
    with served(faults=IGTLFaults(missing_fraction=0.3), seed=4) as m, tracker(m) as t:
        frames = list(t.distinct_frames(100, timeout_s=30))
    missing = sum(f.tools["probe"].missing for f in frames)
    assert 5 < missing < 70
    assert all(f.tools["probe"].usable != f.tools["probe"].missing for f in frames)


def test_no_transform_at_all_is_a_timeout_naming_the_source_and_the_names() -> None:
    faults = IGTLFaults(drop_tools=("marker", "probe"), extra_messages=True)
    with served(faults=faults) as m, tracker(m, timeout_s=0.5) as t:
        with pytest.raises(DeviceTimeout) as e:
            t.read()
    msg = str(e.value)
    assert f"igtl 127.0.0.1:{m.port}" in msg and "no new TRANSFORM frame" in msg
    assert "MarkerToTracker" in msg and "STATUS×" in msg


def test_a_stream_that_stops_is_a_timeout() -> None:
    with served() as m, tracker(m, timeout_s=0.5) as t:
        list(t.distinct_frames(3, timeout_s=10))
        m.close()   # the server goes away: the connection ends
        with pytest.raises((DeviceTimeout, ConnectionLost)):
            for _ in range(10_000):
                t.read()


def test_a_disconnect_is_connection_lost_and_reopening_continues_the_frames() -> None:
    """The source closes the connection (the mock's fault, switched on once frames were read:
    on the fast clock a few frames go in milliseconds, which a busy host may not see before
    the close): ConnectionLost naming host:port until reopened; the source recovered, the
    frame numbers go on from where they were."""
    with served() as m, tracker(m) as t:
        seen = [f.frame for f in t.distinct_frames(3, timeout_s=10)]
        m.faults = IGTLFaults(disconnect_after_frames=1)
        with pytest.raises(ConnectionLost) as e:
            for _ in range(10_000):
                seen.append(t.read().frame)
        assert f"igtl 127.0.0.1:{m.port}" in str(e.value)
        with pytest.raises(ConnectionLost):   # it stays failed until reopened
            t.read()
        t.close()
        m.faults = IGTLFaults()
        t.open()
        after = [f.frame for f in t.distinct_frames(3, timeout_s=10)]
    assert min(after) > max(seen)


def test_the_server_dropping_connections_is_connection_lost() -> None:
    with served() as m, tracker(m) as t:
        list(t.distinct_frames(2, timeout_s=10))
        m.drop_connections()
        with pytest.raises(ConnectionLost, match="closed the connection|connection lost"):
            for _ in range(10_000):
                t.read()


def test_garbage_bytes_are_a_protocol_error_naming_the_source() -> None:
    # the garbage comes 3 frames (3 ms on the fast clock) after the first one, which open
    # waits for: open or a read finds it, as the host's threads run
    with served(faults=IGTLFaults(garbage_after_frames=3)) as m:
        with pytest.raises(ProtocolError) as e, tracker(m) as t:
            for _ in range(1000):
                t.read()
    assert f"igtl 127.0.0.1:{m.port}" in str(e.value)
    assert "not an OpenIGTLink stream" in str(e.value)


def test_a_corrupted_message_is_a_protocol_error_from_open() -> None:
    with served(faults=IGTLFaults(crc_error_prob=1.0)) as m:
        t = tracker(m)
        with pytest.raises(ProtocolError, match=f"igtl 127.0.0.1:{m.port}: .*CRC mismatch"):
            t.open()   # open waits for the first TRANSFORM: this one is corrupt
        assert not t.is_open


def test_an_occasional_corrupted_message_is_a_protocol_error() -> None:
    with served(faults=IGTLFaults(crc_error_prob=0.05), seed=1) as m:
        with pytest.raises(ProtocolError, match="CRC mismatch"):
            with tracker(m) as t:
                for _ in range(10_000):
                    t.read()


def test_a_refused_connection_is_connection_lost_naming_host_and_port() -> None:
    host = unique_host()
    port = free_port(host)   # nothing listens there
    t = IGTLTracker(host, TOOLS, port=port, timeout_s=1.0)
    with pytest.raises(ConnectionLost, match=f"igtl {host}:{port}: connection refused"):
        t.open()
    assert not t.is_open
    t.close()


def test_reading_a_closed_tracker_is_a_device_error() -> None:
    t = IGTLTracker("127.0.0.1", TOOLS)
    with pytest.raises(DeviceError, match="not open"):
        t.read()


@pytest.mark.parametrize("kw, match", [
    ({"host": ""}, "host"),
    ({"port": 0}, "port"),
    ({"port": 70000}, "port"),
    ({"port": True}, "port"),
    ({"tools": {}}, "at least one tool"),
    ({"tools": {"marker": ""}}, "device name"),
    ({"tools": {"marker": "X" * 21}}, "device name"),
    ({"tools": {"marker": "A", "probe": "A"}}, "share one device name"),
    ({"timeout_s": 0}, "timeout_s"),
    ({"timeout_s": float("nan")}, "timeout_s"),
])
def test_bad_arguments_are_refused(kw: dict[str, Any], match: str) -> None:
    args: dict[str, Any] = {"host": "127.0.0.1", "tools": TOOLS, **kw}
    with pytest.raises(ValueError, match=match):
        IGTLTracker(args.pop("host"), args.pop("tools"), **args)


def test_an_ipv6_loopback_source() -> None:
    try:
        m = IGTLTrackerMock(_rig(), TOOLS, host="::1", port=0, clock=FAST)
        m.start()
    except OSError as e:  # pragma: no cover - a machine without IPv6 loopback
        pytest.skip(f"no IPv6 loopback here ({e})")
    try:
        assert m.endpoint == f"[::1]:{m.port}"
        with IGTLTracker("::1", TOOLS, port=m.port) as t:
            assert t.read().tools["marker"].usable
    finally:
        m.close()
    t = IGTLTracker("::1", TOOLS, port=m.port, timeout_s=1.0)   # nothing listens there now
    with pytest.raises(ConnectionLost, match=rf"igtl \[::1\]:{m.port}: connection refused"):
        t.open()
