"""A connection that fails says where and what to check, in one wording for every driver
(``tmscal.net.connect_problem``, the drivers' error translation): refused, no answer, no route,
a name that does not resolve. The refusals are real: a loopback port nothing listens on,
reached through the NDI (pyserial's socket://), OpenIGTLink and DENSO b-CAP drivers."""

from __future__ import annotations

import errno
import socket

import pytest
import serial

from tests.rigs import free_port, unique_host
from tmscal.drivers.denso.client import BCAPClient
from tmscal.drivers.igtl.tracker import IGTLTracker
from tmscal.drivers.ndi.wire import open_port
from tmscal.errors import ConnectionLost, DeviceTimeout
from tmscal.net import connect_problem, socket_error


def _refused_address() -> tuple[str, int]:
    host = unique_host()
    return host, free_port(host)  # nothing listens there


def test_ndi_socket_refused_names_the_address_the_key_and_what_to_check() -> None:
    """Before: "Could not open port socket://…: [Errno 111] Connection refused"."""
    host, port = _refused_address()
    with pytest.raises(ConnectionLost) as e:
        open_port("ndi", f"socket://{host}:{port}", 1.0, None)
    msg = str(e.value)
    assert msg.startswith(f"ndi: cannot open socket://{host}:{port}: connection refused by "
                          f"{host}:{port} (TCP)"), msg
    assert "check the device's IP address and port (tracker.port)" in msg
    assert "firewall" in msg and "8765" in msg  # a Vega's API port, for the hint
    assert "Errno" not in msg


def test_igtl_and_bcap_refusals_say_the_same() -> None:
    host, port = _refused_address()
    t = IGTLTracker(host, {"marker": "MarkerToTracker"}, port=port, timeout_s=1.0)
    with pytest.raises(ConnectionLost) as e:
        t.open()
    t.close()
    assert f"connection refused by {host}:{port} (TCP)" in str(e.value)
    assert "(tracker.host, tracker.port)" in str(e.value) and "PlusServer" in str(e.value)
    host, port = _refused_address()
    with pytest.raises(ConnectionLost) as e:
        BCAPClient(host, port, timeout_s=1.0).connect()
    assert f"connection refused by {host}:{port} (TCP)" in str(e.value)
    assert "(robot.host, robot.port)" in str(e.value) and "b-CAP" in str(e.value)


@pytest.mark.parametrize("exc, words", [
    (TimeoutError("timed out"), ["no answer from 10.0.0.5:8765 (TCP) within 5 s",
                                 "powered on", "no firewall blocks TCP port 8765"]),
    (OSError(errno.ETIMEDOUT, "Connection timed out"), ["no answer from 10.0.0.5:8765"]),
    (OSError(errno.EHOSTUNREACH, "No route to host"), ["no route to 10.0.0.5:8765 (TCP)",
                                                       "subnet"]),
    (OSError(errno.ENETUNREACH, "Network is unreachable"), ["no route to 10.0.0.5:8765"]),
    (socket.gaierror(socket.EAI_NONAME, "Name or service not known"),
     ["cannot resolve the host name '10.0.0.5'"]),
    (ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused"),
     ["connection refused by 10.0.0.5:8765 (TCP)"]),
])
def test_each_failure_says_what_it_was_and_names_the_key(exc, words) -> None:
    msg = connect_problem(exc, "10.0.0.5", 8765, "tracker.port", 5.0)
    assert msg is not None and "(tracker.port)" in msg, msg
    for w in words:
        assert w in msg, (w, msg)


def test_the_socket_error_is_found_behind_a_library_wrapper() -> None:
    """pyserial raises SerialException (an OSError without errno) from the socket error."""
    try:
        try:
            raise ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused")
        except OSError as inner:
            raise serial.SerialException(f"Could not open port: {inner}") from None
    except serial.SerialException as outer:
        assert isinstance(socket_error(outer), ConnectionRefusedError)
        assert "connection refused" in connect_problem(outer, "h", 1, "k")
    assert connect_problem(ValueError("bad"), "h", 1, "k") is None


def test_an_igtl_connect_timeout_is_a_device_timeout(monkeypatch) -> None:
    def no_answer(*a, **k):
        raise TimeoutError("timed out")

    monkeypatch.setattr(socket, "create_connection", no_answer)
    t = IGTLTracker("10.0.0.5", {"marker": "MarkerToTracker"}, port=18944, timeout_s=0.5)
    with pytest.raises(DeviceTimeout, match=r"no answer from 10\.0\.0\.5:18944 \(TCP\) "
                                            r"within 0\.5 s"):
        t.open()
    t.close()
