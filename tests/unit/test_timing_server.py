"""The shared Deadline and the mock-server base: a fake clock for the deadline; real loopback
sockets for the listener."""

from __future__ import annotations

import math
import socket
import threading

import pytest

from tmscal.errors import ConfigError
from tmscal.mocks.server import TCPListener
from tmscal.timing import Deadline


class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_deadline_counts_down_and_restarts():
    c = _Clock()
    d = Deadline(2.0, clock=c)
    assert d.remaining() == 2.0 and not d.expired()
    c.t += 1.5
    assert d.remaining() == pytest.approx(0.5) and not d.expired()
    c.t += 0.5
    assert d.expired() and d.remaining() == 0.0
    d.restart()
    assert d.remaining() == 2.0
    assert Deadline(None, clock=c).remaining() == math.inf
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError):
            Deadline(bad)


def test_listener_serves_each_connection_and_drops_them_on_close():
    got: list[bytes] = []
    ended = threading.Event()

    def echo(conn: socket.socket) -> None:
        while True:
            data = conn.recv(100)
            if not data:
                ended.set()
                return
            got.append(data)
            conn.sendall(data.upper())

    srv = TCPListener("127.0.0.1", 0, echo, "echo")
    host, port = srv.start().rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=5) as c:
        c.sendall(b"abc")
        assert c.recv(100) == b"ABC"
        srv.close()
        assert ended.wait(5)
        assert c.recv(100) == b""  # the server shut the connection
    assert got == [b"abc"] and srv.accepted == 1 and srv.connections == 0


def test_listener_refuses_non_loopback_before_binding():
    with pytest.raises(ConfigError, match="loopback"):
        TCPListener("0.0.0.0", 0, lambda c: None, "test")
