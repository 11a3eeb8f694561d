"""The OpenIGTLink tracker's own config keys (``tracker: {driver: igtl, ...}``).

``host`` (the PlusServer or other OpenIGTLink source; required), ``port`` (1…65535, default
18944), ``timeout_s`` (s, > 0, default 2), and the values of the generic ``tools`` mapping:
each tool's TRANSFORM device name, 1…20 bytes of ASCII (OpenIGTLink's char[20]; PlusServer
sends the first 20 characters of a longer transform name). ``frame_rate_hz`` and ``options``
are the generic section's. Every problem is a ``ConfigError`` naming the key:
``<config>: key 'tracker.port': ...``. docs/devices.md, "OpenIGTLink tracker (PlusServer)".
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Self

from ...errors import ConfigError
from .tracker import DEFAULT_PORT
from .wire import MAX_NAME_BYTES

__all__ = ["IGTLSettings"]


def _err(src: str, key: str, msg: str) -> ConfigError:
    return ConfigError(f"{src}: key 'tracker.{key}': {msg}")


def _show(v: Any) -> str:
    r = repr(v)
    return r if len(r) <= 60 else r[:59] + "…"


@dataclass(frozen=True)
class IGTLSettings:
    """Where the OpenIGTLink source is and how long to wait for it: ``host``, ``port``
    (TCP), ``timeout_s`` (s), and ``tools`` (our tool name → TRANSFORM device name)."""

    SECTION: ClassVar[str] = "tracker"
    KEYS: ClassVar[tuple[str, ...]] = ("host", "port", "timeout_s")
    #: the options the driver accepts beside KEYS: ``ask_metadata`` (bool)
    OPTIONS: ClassVar[Mapping[str, Any] | None] = None
    ADDRESS_KEY: ClassVar[str] = "host"

    host: str = ""
    port: int = DEFAULT_PORT
    timeout_s: float = 2.0
    tools: dict[str, str] = field(default_factory=dict, kw_only=True)
    src: str = field(default="<config>", kw_only=True, compare=False)

    @classmethod
    def parse(cls, section: Mapping[str, Any], src: str, base_dir: Path | None,
              check_files: bool) -> Self:
        """The settings of the tracker ``section`` (the whole mapping; the generic keys are
        not checked here). ``base_dir`` and ``check_files`` are unused: this driver reads no
        files."""
        host = cls._host(section.get("host"), src)
        port = cls._port(section.get("port", DEFAULT_PORT), src)
        timeout = section.get("timeout_s", 2.0)
        if isinstance(timeout, bool) or not isinstance(timeout, int | float) \
                or not math.isfinite(timeout) or timeout <= 0:
            raise _err(src, "timeout_s", f"expected a number of seconds > 0, got "
                                         f"{_show(timeout)}")
        tools = section.get("tools") or {}
        if not isinstance(tools, Mapping):
            raise _err(src, "tools", f"expected a mapping of tool name → TRANSFORM device "
                                     f"name, got {_show(tools)}")
        parsed = {str(k): cls.parse_tool(str(k), v, src, base_dir, check_files)
                  for k, v in tools.items()}
        return cls(host, port, float(timeout), tools=parsed, src=src)

    @classmethod
    def parse_tool(cls, name: str, value: Any, src: str, base_dir: Path | None,
                   check_files: bool) -> str:
        """Tool ``name``'s TRANSFORM device name: 1…20 bytes of printable ASCII."""
        key = f"tools.{name}"
        if not isinstance(value, str) or not value:
            raise _err(src, key, f"expected the device name of the tool's TRANSFORM (e.g. "
                                 f"'MarkerToTracker'), got {_show(value)}")
        if not value.isascii() or not value.isprintable():
            raise _err(src, key, f"{_show(value)}: a device name is printable ASCII")
        if len(value) > MAX_NAME_BYTES:
            raise _err(src, key, f"{_show(value)} is {len(value)} bytes; OpenIGTLink device "
                                 f"names are at most {MAX_NAME_BYTES} (PlusServer sends the "
                                 f"first {MAX_NAME_BYTES}: {value[:MAX_NAME_BYTES]!r})")
        return value

    @staticmethod
    def _host(v: Any, src: str) -> str:
        if not isinstance(v, str) or not v.strip() or any(c.isspace() for c in v):
            raise _err(src, "host", f"expected the address of the OpenIGTLink source (e.g. "
                                    f"127.0.0.1 or plus-pc.local), got {_show(v)}")
        return v

    @staticmethod
    def _port(v: Any, src: str) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 65535:
            raise _err(src, "port", f"expected a TCP port 1…65535 (PlusServer's default "
                                    f"{DEFAULT_PORT}), got {_show(v)}")
        return v

    def kwargs(self) -> dict[str, Any]:
        """The ``IGTLTracker`` keyword arguments: ``tools``, ``host``, ``port``,
        ``timeout_s``."""
        return {"tools": dict(self.tools), "host": self.host, "port": self.port,
                "timeout_s": self.timeout_s}

    def address(self) -> str:
        """``host:port`` (an IPv6 host in brackets)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    def with_address(self, text: str) -> Self:
        """These settings at ``text``: ``host:port``, ``[v6 host]:port`` or a host alone
        (the port kept), checked as ``parse`` checks ``host`` and ``port``; ConfigError
        naming ``tracker.host`` (or ``tracker.port``) and the override."""
        src = f"{self.src} (override {text!r})"
        if not isinstance(text, str):
            raise _err(src, "host", f"expected host or host:port, got {_show(text)}")
        host, port = text, self.port
        if text.startswith("["):
            inner, sep, rest = text[1:].partition("]")
            if not sep or (rest and not rest.startswith(":")):
                raise _err(src, "host", "expected [v6 address] or [v6 address]:port")
            host, rest = inner, rest[1:]
            port = self._port_text(rest, src) if rest else port
        elif text.count(":") == 1:
            host, _, rest = text.partition(":")
            port = self._port_text(rest, src)
        return dataclasses.replace(self, host=self._host(host, src), port=port)

    def _port_text(self, text: str, src: str) -> int:
        if not (text.isascii() and text.isdigit() and len(text) <= 5):
            raise _err(src, "port", f"expected a TCP port 1…65535 after ':', got "
                                    f"{_show(text)}")
        return self._port(int(text), src)
