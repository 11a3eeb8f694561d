"""``tmscal.stream.StreamServer``'s per-client limits with real loopback sockets (issue 22,
item 8): a client that reads nothing loses its oldest frames and is disconnected once it has
taken no data for ``stall_s`` while frames waited, and a reading client beside it keeps
receiving every frame's messages in order. (The end-to-end tests with ``tmscal stream`` and a
mock Polaris are in tests/e2e/test_stream.py.)"""

from __future__ import annotations

import socket
import threading

import numpy as np
from pyigtl.messages import MessageBase

from tests.rigs import wait_until
from tmscal.stream import StreamServer
from tmscal.timing import Deadline


def _feed(srv: StreamServer, stop: threading.Event) -> None:
    """Frames as fast as the server takes them: one TRANSFORM a frame, its timestamp the
    frame number."""
    i = 0
    while not stop.is_set():
        M = np.eye(4)
        M[:3, 3] = [i, 0.0, 0.0]
        srv.send_transforms({"CoilToTracker": M}, float(i))
        i += 1
        stop.wait(0.0005)


def _messages(sock: socket.socket, n: int) -> list[float]:
    """The timestamps of the next ``n`` messages on ``sock``."""
    buf, out = b"", []
    while len(out) < n:
        chunk = sock.recv(65536)
        assert chunk, "the server closed the reading client"
        buf += chunk
        while len(buf) >= 58:
            size = MessageBase.parse_header(buf[:58])["body_size"]
            if len(buf) < 58 + size:
                break
            out.append(MessageBase.parse_header(buf[:58])["timestamp"])
            buf = buf[58 + size:]
    return out


def test_a_client_that_reads_nothing_is_dropped_and_the_reader_keeps_its_frames():
    with StreamServer("127.0.0.1", 0, queue_frames=4, stall_s=1.0,
                      socket_buffer_bytes=4096) as srv:
        slow = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        slow.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        slow.connect(("127.0.0.1", srv.port))
        reader = socket.create_connection(("127.0.0.1", srv.port), timeout=30)
        wait_until(lambda: len(srv.peers) == 2, 30.0, "both clients connected")
        slow_peer = "{}:{}".format(*slow.getsockname())
        stop = threading.Event()
        feeder = threading.Thread(target=_feed, args=(srv, stop), daemon=True)
        feeder.start()
        try:
            seen: list[float] = []
            guard = Deadline(60.0)
            while slow_peer in srv.peers:  # until the server drops the client reading nothing
                seen += _messages(reader, 50)
                assert not guard.expired(), "the client that reads nothing was never dropped"
            assert srv.dropped > 0  # its oldest frames were dropped before it went
            seen += _messages(reader, 50)  # the reader is still served
            assert srv.peers == ["{}:{}".format(*reader.getsockname())]
            assert seen == sorted(seen)  # in order (frames dropped for a slow reader only)
        finally:
            stop.set()
            feeder.join(10)
        slow.settimeout(10)
        got = b"x"
        while got:  # what was in flight, then the end of the stream
            try:
                got = slow.recv(65536)
            except ConnectionResetError:
                break
        slow.close()
        reader.close()
