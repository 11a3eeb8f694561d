"""The OpenIGTLink tracker mock on its own, read with raw loopback sockets and the codec:
what PlusServer does towards a client (version 1 until the client sends version 2,
``GET_STATUS`` answered, one timestamp per frame, UTC stamps), the fast clock's tracker time,
loopback-only binding and its argument checks."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from tests.rigs import quiet_tms_rig, wait_until
from tmscal.drivers.igtl import wire
from tmscal.errors import ConfigError
from tmscal.mocks.clock import FAST, REAL_TIME
from tmscal.mocks.igtl import IGTLFaults, IGTLTrackerMock


class Reader:
    """A raw OpenIGTLink client: a socket and the messages read from it."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
        self.buf = bytearray()

    def message(self) -> tuple[wire.Header, bytes]:
        while True:
            if len(self.buf) >= wire.HEADER_SIZE:
                h = wire.parse_header(bytes(self.buf[:wire.HEADER_SIZE]))
                end = wire.HEADER_SIZE + h.body_size
                if len(self.buf) >= end:
                    body = bytes(self.buf[wire.HEADER_SIZE:end])
                    del self.buf[:end]
                    return h, body
            chunk = self.sock.recv(65536)
            assert chunk, "the mock closed the connection"
            self.buf += chunk

    def transforms(self, n: int) -> list[wire.Transform]:
        out = []
        while len(out) < n:
            h, body = self.message()
            if h.type == "TRANSFORM":
                out.append(wire.decode_transform(h, body))
        return out

    def close(self) -> None:
        self.sock.close()


@contextmanager
def served(**kw) -> Iterator[IGTLTrackerMock]:
    kw.setdefault("clock", FAST)
    m = IGTLTrackerMock(kw.pop("rig", None) or quiet_tms_rig(), port=0, **kw)
    m.start()
    try:
        yield m
    finally:
        m.close()


def test_a_client_gets_version_1_transforms_of_every_body_one_stamp_per_frame() -> None:
    rig = quiet_tms_rig()
    with served(rig=rig) as m:
        r = Reader(m.port)
        ts = r.transforms(20)
        r.close()
    assert {t.version for t in ts} == {1} and all(not t.metadata for t in ts)
    assert {t.device for t in ts} == {"MarkerToTracker", "ProbeToTracker"}
    by_stamp: dict[int, set[str]] = {}
    for t in ts:
        by_stamp.setdefault(t.stamp, set()).add(t.device)
    assert all(len(d) <= 2 for d in by_stamp.values()) and len(by_stamp) >= 9
    for t in ts:
        body = "marker" if t.device == "MarkerToTracker" else "probe"
        np.testing.assert_allclose(t.matrix, rig.true_body(body), atol=1e-3)


def test_a_version_2_message_makes_it_answer_in_version_2_with_a_status() -> None:
    with served() as m:
        r = Reader(m.port)
        r.sock.sendall(wire.encode("GET_STATUS", version=2))
        while True:
            h, _ = r.message()
            if h.type == "STATUS":   # the answer to GET_STATUS
                assert h.version == 2
                break
        t = r.transforms(4)[-1]
        r.close()
    assert t.version == 2 and t.metadata == {"TransformStatus": "OK"}


def test_real_time_stamps_are_utc_seconds() -> None:
    with served(clock=REAL_TIME) as m:
        r = Reader(m.port)
        t = r.transforms(1)[0]
        r.close()
    assert abs(t.timestamp - time.time()) < 60.0


def test_a_late_real_time_sender_sends_the_frames_it_missed_each_with_its_own_stamp() -> None:
    """The sender held up for 0.3 s (its lock taken, as by a busy host) sends the frames it
    missed when it runs again, as PlusServer sends the frames since its last one: the stamps
    stay one period apart across the hold, none missing."""
    with served(clock=REAL_TIME, rate_hz=50.0) as m:
        r = Reader(m.port)
        first = r.transforms(10)
        with m._lock:  # the sender cannot make a frame meanwhile
            time.sleep(0.3)
        rest = r.transforms(60)
        r.close()
    stamps = sorted({t.stamp for t in first + rest})
    steps = np.diff([s / 2**32 for s in stamps])
    assert len(stamps) >= 35
    np.testing.assert_allclose(steps, 1 / 50.0, atol=1e-6)


def test_fast_stamps_are_a_nominal_period_apart() -> None:
    with served(rate_hz=50.0) as m:
        r = Reader(m.port)
        stamps = sorted({t.stamp for t in r.transforms(20)})
        r.close()
    steps = np.diff([s / 2**32 for s in stamps])
    np.testing.assert_allclose(steps, 1 / 50.0, atol=1e-6)


def test_fast_tracker_time_advances_only_while_a_client_is_connected() -> None:
    with served(rate_hz=50.0) as m:
        assert m.tracker_time_s() == 0.0
        r = Reader(m.port)
        r.transforms(10)
        assert m.tracker_time_s() >= 4 / 50.0
        r.close()
        wait_until(lambda: m.connections == 0, 5.0, "the mock to see the client go")
        t = m.tracker_time_s()
        time.sleep(0.1)
        assert m.tracker_time_s() == t


def test_every_client_gets_the_same_frames() -> None:
    with served() as m:
        a, b = Reader(m.port), Reader(m.port)
        wait_until(lambda: m.connections == 2, 5.0, "two clients")
        sa = {t.stamp for t in a.transforms(40)}
        sb = {t.stamp for t in b.transforms(40)}
        a.close()
        b.close()
    assert sa & sb


def test_bytes_that_are_not_openigtlink_close_the_connection() -> None:
    with served() as m:
        r = Reader(m.port)
        r.sock.sendall(b"GET / HTTP/1.1\r\n" * 8)
        wait_until(lambda: m.connections == 0, 5.0, "the mock to close the connection")
        r.close()


@pytest.mark.parametrize("host", ["0.0.0.0", "8.8.8.8", "::"])
def test_it_binds_to_loopback_only(host: str) -> None:
    with pytest.raises(ConfigError, match="loopback"):
        IGTLTrackerMock(quiet_tms_rig(), host=host, port=0)


def test_it_listens_on_loopback() -> None:
    with served() as m:
        assert m._listeners[0].getsockname()[0] == "127.0.0.1"
        assert m.endpoint == f"127.0.0.1:{m.port}"


def test_there_is_no_pty_transport() -> None:
    with pytest.raises(ConfigError, match="TCP only"):
        IGTLTrackerMock(quiet_tms_rig(), port=0).start_pty()


@pytest.mark.parametrize("kw, match", [
    ({"tools": {"coil": "CoilToTracker"}}, "not a body"),
    ({"tools": {"marker": "X" * 21}}, "device name"),
    ({"faults": IGTLFaults(drop_tools=("coil",))}, "not one of the tools"),
    ({"rate_hz": 0}, "rate_hz"),
    ({"fast_rate_hz": 1e6}, "fast_rate_hz"),
    ({"header_version": 3}, "header_version"),
])
def test_bad_arguments_are_refused(kw, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        IGTLTrackerMock(quiet_tms_rig(), port=0, **kw)


@pytest.mark.parametrize("kw, match", [
    ({"missing_fraction": 1.5}, "missing_fraction"),
    ({"crc_error_prob": -0.1}, "crc_error_prob"),
    ({"disconnect_after_frames": -1}, "disconnect_after_frames"),
    ({"garbage_after_frames": 1.5}, "garbage_after_frames"),
    ({"drop_tools": "probe"}, "drop_tools"),
    ({"stale_tools": [3]}, "stale_tools"),
    ({"extra_messages": "yes"}, "extra_messages"),
])
def test_bad_faults_are_refused(kw, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        IGTLFaults(**kw)


def test_faults_take_lists_from_a_config() -> None:
    f = IGTLFaults(drop_tools=["probe"], stale_tools=["marker"])
    assert f.drop_tools == ("probe",) and f.stale_tools == ("marker",)
