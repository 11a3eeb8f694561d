"""The OpenIGTLink tracker's own config keys (``tracker: {driver: igtl, ...}``), read by the
config parser through the driver registry (``tmscal.config.settings``, the settings protocol).

``host`` (the PlusServer or other OpenIGTLink source; required), ``port`` (1…65535, default
18944), and the values of the generic ``tools`` mapping:
each tool's TRANSFORM device name, 1…20 bytes of ASCII (OpenIGTLink's char[20]; PlusServer
sends the first 20 characters of a longer transform name). ``frame_rate_hz`` is the generic
section's; ``tracker.options`` takes ``timeout_s`` (s) and ``ask_metadata`` (bool); the key
``tracker.timeout_s`` of older configs is refused naming ``tracker.options.timeout_s``. Every
problem is a ``ConfigError`` naming the key: ``<config>: key 'tracker.port': ...``. docs/devices.md,
"OpenIGTLink tracker (PlusServer)".
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Self

from ...config.settings import Option, TrackerSettings
from ...config.values import err, show
from .wire import MAX_NAME_BYTES

__all__ = ["IGTLSettings", "DEFAULT_PORT"]

#: PlusServer's usual port (the OpenIGTLink registered port)
DEFAULT_PORT = 18944


@dataclass(frozen=True)
class IGTLSettings(TrackerSettings):
    """Where the OpenIGTLink source is: ``host``, ``port`` (TCP), and ``tools`` (our tool
    name → TRANSFORM device name). The base class's ``kwargs()`` gives ``IGTLTracker``
    these as they are (``make_tracker`` adds ``frame_rate_hz`` and the options)."""

    KEYS: ClassVar[tuple[str, ...]] = ("host", "port")
    OPTIONS: ClassVar[Mapping[str, Option]] = {
        "timeout_s": Option(float, above=0, hi=3600, default=2.0, unit="s",
                            help="the longest wait for the connection and for a new frame"),
        "ask_metadata": Option(
            bool, default=True,
            help="send one `GET_STATUS` with header version 2 after connecting, so that "
                 "PlusServer answers in version 2 and its TRANSFORMs carry `TransformStatus`"),
    }
    MOVED: ClassVar[Mapping[str, str]] = {"timeout_s": "options.timeout_s"}
    ADDRESS_KEY: ClassVar[str] = "host"

    host: str = ""
    port: int = DEFAULT_PORT

    @classmethod
    def parse(cls, section: Mapping[str, Any], src: str, base_dir: Path | None,
              check_files: bool) -> Self:
        """The settings of the tracker ``section`` (the whole mapping; its generic keys are
        the config parser's). ``base_dir`` and ``check_files`` are unused: this driver reads
        no files."""
        host = cls._host(section.get("host"), src)
        port = cls._port(section.get("port", DEFAULT_PORT), src)
        tools = section.get("tools") or {}
        if not isinstance(tools, Mapping):
            raise err(src, "tracker.tools", "expected a mapping of tool name → TRANSFORM "
                      f"device name, got {show(tools)}")
        parsed = {str(k): cls.parse_tool(str(k), v, src, base_dir, check_files)
                  for k, v in tools.items()}
        return cls(host, port, tools=parsed, src=src)

    @classmethod
    def parse_tool(cls, name: str, value: Any, src: str, base_dir: Path | None,
                   check_files: bool) -> str:
        """Tool ``name``'s TRANSFORM device name: 1…20 bytes of printable ASCII."""
        key = f"tracker.tools.{name}"
        if not isinstance(value, str) or not value:
            raise err(src, key, "expected the device name of the tool's TRANSFORM (e.g. "
                      f"'MarkerToTracker'), got {show(value)}")
        if not value.isascii() or not value.isprintable():
            raise err(src, key, f"{show(value)}: a device name is printable ASCII")
        if len(value) > MAX_NAME_BYTES:
            raise err(src, key, f"{show(value)} is {len(value)} bytes; OpenIGTLink device "
                      f"names are at most {MAX_NAME_BYTES} (PlusServer sends the first "
                      f"{MAX_NAME_BYTES}: {value[:MAX_NAME_BYTES]!r})")
        return value

    @staticmethod
    def _host(v: Any, src: str) -> str:
        if not isinstance(v, str) or not v.strip() or any(c.isspace() for c in v):
            raise err(src, "tracker.host", "expected the address of the OpenIGTLink source "
                      f"(e.g. 127.0.0.1 or plus-pc.local), got {show(v)}")
        return v

    @staticmethod
    def _port(v: Any, src: str) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 65535:
            raise err(src, "tracker.port", "expected a TCP port 1…65535 (PlusServer's "
                      f"default {DEFAULT_PORT}), got {show(v)}")
        return v

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
            raise err(src, "tracker.host", f"expected host or host:port, got {show(text)}")
        host, port = text, self.port
        if text.startswith("["):
            inner, sep, rest = text[1:].partition("]")
            if not sep or (rest and not rest.startswith(":")):
                raise err(src, "tracker.host", "expected [v6 address] or [v6 address]:port")
            host, rest = inner, rest[1:]
            port = self._port_text(rest, src) if rest else port
        elif text.count(":") == 1:
            host, _, rest = text.partition(":")
            port = self._port_text(rest, src)
        return dataclasses.replace(self, host=self._host(host, src), port=port)

    def _port_text(self, text: str, src: str) -> int:
        if not (text.isascii() and text.isdigit() and len(text) <= 5):
            raise err(src, "tracker.port",
                      f"expected a TCP port 1…65535 after ':', got {show(text)}")
        return self._port(int(text), src)
