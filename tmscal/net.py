"""Network addresses: loopback-only binding (the mock devices, ``tmscal stream``'s check of
its host) and endpoint strings ("host:port", "[v6]:port").

The mocks answer anything they are sent and move a simulated rig on request: they must never
be reachable from another machine. Hosts are compared as addresses, not by spelling: an IP
literal must be a loopback address (127.0.0.0/8 or ::1), and a name (``localhost``) must
resolve to loopback addresses only.
"""

from __future__ import annotations

import errno
import ipaddress
import socket

from .errors import ConfigError

__all__ = ["NotLoopbackError", "loopback_family", "is_loopback", "url_host",
           "split_endpoint", "listen_error", "tcp_probe", "connect_problem", "socket_error"]


class NotLoopbackError(ConfigError, ValueError):
    """A mock endpoint that is not a loopback address. A ``ConfigError`` (one ``error:`` line
    from the CLI); also a ``ValueError``, as an invalid constructor argument of a mock."""


def _addresses(host: str, what: str) -> list[ipaddress.IPv4Address | ipaddress.IPv6Address]:
    try:
        return [ipaddress.ip_address(host)]
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None, socket.AF_UNSPEC, socket.SOCK_STREAM)
    except (OSError, UnicodeError) as e:
        raise NotLoopbackError(f"{what}: cannot resolve {host!r} ({e}); the mocks bind to "
                          "loopback only (127.0.0.0/8, ::1, localhost)") from None
    out = []
    for info in infos:
        addr = str(info[4][0]).split("%", 1)[0]  # drop an IPv6 scope id
        out.append(ipaddress.ip_address(addr))
    return out


def loopback_family(host: str, what: str) -> socket.AddressFamily:
    """The socket family to bind ``host`` with (AF_INET, or AF_INET6 for an IPv6-only name
    such as ``::1``). Raises ``NotLoopbackError`` (a ``ConfigError``) naming ``what`` and
    ``host`` unless every address ``host`` stands for is a loopback address (``0.0.0.0``,
    ``::`` and public addresses are refused)."""
    if not isinstance(host, str) or not host:
        raise NotLoopbackError(f"{what}: no host given; the mocks bind to loopback only "
                          "(127.0.0.0/8, ::1, localhost)")
    addrs = _addresses(host, what)
    bad = [a for a in addrs if not a.is_loopback]
    if not addrs or bad:
        shown = f" (resolves to {bad[0]})" if bad and str(bad[0]) != host else ""
        raise NotLoopbackError(f"{what}: {host!r}{shown} is not a loopback address; the mocks "
                          "bind to loopback only (127.0.0.0/8, ::1, localhost)")
    if any(a.version == 4 for a in addrs):
        return socket.AF_INET
    return socket.AF_INET6


def is_loopback(host: str) -> bool:
    """True when every address ``host`` stands for is a loopback address (127.0.0.0/8, ::1,
    ``localhost``); False for anything else, including a name that does not resolve."""
    try:
        loopback_family(host, "--host")
    except NotLoopbackError:
        return False
    return True


def url_host(host: str) -> str:
    """``host`` as written in a URL (an IPv6 literal in brackets)."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def split_endpoint(ep: str) -> tuple[str, int | None]:
    """"host", "host:port", "[v6]" or "[v6]:port" → (host, port or None)."""
    if ep.startswith("["):
        host, _, rest = ep[1:].partition("]")
        return host, int(rest[1:]) if rest.startswith(":") else None
    if ep.count(":") == 1:
        host, _, port = ep.partition(":")
        return host, int(port)
    return ep, None


def listen_error(e: OSError, what: str, host: str, port: int, proto: str = "TCP") -> OSError:
    """The ``OSError`` of a mock that cannot bind ``host:port``, naming ``what``, the address
    and the port, and for an address in use what to do (``errno`` kept; its text is the
    message, which the CLI prints as one line)."""
    where = f"{what}: cannot listen on {url_host(host)}:{port} ({proto})"
    if e.errno == errno.EADDRINUSE:
        msg = (f"{where}: the address is already in use, by another tmscal mock or another "
               "program (stop it, e.g. the earlier `tmscal mock`, or give the config's mock "
               "another loopback address)")
    else:
        msg = f"{where}: {e.strerror or e}"
    return OSError(e.errno, msg)


def tcp_probe(host: str, port: int, timeout_s: float) -> str | None:
    """Open (and close) a TCP connection to ``host:port``: None when it is accepted, else why
    not, as "refused" (something answers at the address but nothing listens on the port),
    "timeout" (no answer within ``timeout_s``: a wrong address, a cable, a device that is
    off) or the system's text (no route to host, a name that does not resolve, …)."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return None
    except ConnectionRefusedError:
        return "refused"
    except TimeoutError:
        return "timeout"
    except OSError as e:
        return str(e.strerror or e)


#: errno values of "no route": the host is not on any network this computer reaches
_NO_ROUTE = {errno.EHOSTUNREACH, errno.ENETUNREACH, errno.EHOSTDOWN, errno.ENETDOWN,
             errno.EADDRNOTAVAIL}


def socket_error(e: BaseException | None) -> OSError | None:
    """The socket error behind ``e``: ``e`` itself, or the first ``OSError`` in its chain of
    causes and contexts (a library that wraps it, as pyserial's ``SerialException`` does), or
    None when there is none."""
    seen: set[int] = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, (OSError, TimeoutError)) and (
                isinstance(e, (TimeoutError, socket.gaierror, ConnectionError))
                or e.errno is not None):
            return e
        e = e.__cause__ or e.__context__
    return None


def connect_problem(e: BaseException, host: str, port: int | str, key: str,
                    timeout_s: float | None = None, proto: str = "TCP",
                    service: str = "") -> str | None:
    """What a failed connection to ``host:port`` (``proto`` TCP or UDP) means and what to
    check, in one sentence naming the address and the config ``key`` it came from; None when
    ``e`` holds no socket error (:func:`socket_error`). The one wording of the drivers' error
    translation for the failures of the network:

    * refused: the host answered but nothing listens on that port (a wrong port; the device's
      ``service``, e.g. "PlusServer", not running);
    * timed out (``timeout_s``): nothing answered (a wrong address, the device off or on
      another network, a firewall dropping the port);
    * no route to the host, a name that does not resolve: the address, this computer's
      network;
    * anything else: the system's text and the address."""
    se = socket_error(e)
    if se is None:
        return None
    where = f"{url_host(host)}:{port} ({proto})"
    what = f" ({service})" if service else ""
    check_ip = f"check the device's IP address and port ({key})"
    if isinstance(se, ConnectionRefusedError) or se.errno == errno.ECONNREFUSED:
        return (f"connection refused by {where}: the host answers but nothing listens on "
                f"port {port} (or a firewall rejects it); {check_ip}, and that the device's "
                f"service{what} is running")
    if isinstance(se, TimeoutError) or se.errno == errno.ETIMEDOUT:
        within = f" within {timeout_s:g} s" if timeout_s else ""
        return (f"no answer from {where}{within}: {check_ip}, that the device is powered "
                f"on and on this computer's network, and that no firewall blocks {proto} port "
                f"{port}")
    if isinstance(se, socket.gaierror):
        return (f"cannot resolve the host name {host!r} ({se.strerror or se}): check the "
                f"address ({key}) and this computer's name service")
    if se.errno in _NO_ROUTE:
        return (f"no route to {where} ({se.strerror or se}): {check_ip}, and that this "
                "computer is on the device's network (its cable, its IP settings and subnet)")
    return f"cannot connect to {where}: {se.strerror or se}; {check_ip}"
