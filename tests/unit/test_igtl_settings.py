"""The OpenIGTLink tracker's config keys (``drivers.igtl.settings``): what a section gives
the driver, and every bad value refused with a ConfigError naming the config and the key."""

from __future__ import annotations

from typing import Any

import pytest

from tmscal.config import load_config, parse_config
from tmscal.drivers.igtl.settings import IGTLSettings
from tmscal.drivers.igtl.tracker import IGTLTracker
from tmscal.errors import ConfigError

SRC = "rigs/plus.yaml"
SECTION = {"driver": "igtl", "host": "192.168.1.20", "port": 18945,
           "frame_rate_hz": 60, "tools": {"marker": "MarkerToTracker",
                                          "probe": "ProbeToTracker"}}


def parse(**changes: Any) -> IGTLSettings:
    section = {**SECTION, **changes}
    for k in [k for k, v in changes.items() if v is _DROP]:
        del section[k]
    return IGTLSettings.parse(section, SRC, None, True)


_DROP = object()


@pytest.mark.parametrize("value", [0, -1, float("nan"), float("inf"), 3601, "2", False])
def test_a_bad_timeout_option_names_its_key(value: Any) -> None:
    with pytest.raises(ConfigError) as e:
        parse_config({"tracker": {**SECTION, "options": {"timeout_s": value}}}, SRC)
    assert str(e.value).startswith(f"{SRC}: key 'tracker.options.timeout_s': ")


def test_the_timeout_option_reaches_the_driver() -> None:
    cfg = parse_config({"tracker": {**SECTION, "options": {"timeout_s": 1.5}}}, SRC)
    assert cfg.tracker is not None and cfg.tracker.options == {"timeout_s": 1.5}
    assert IGTLTracker(**cfg.tracker.settings.kwargs(), **cfg.tracker.options).timeout_s == 1.5


def test_the_old_timeout_key_names_its_new_spelling(tmp_path) -> None:
    """``tracker.timeout_s`` was a key of this driver; it is an option now (docs/configs.md,
    "General rules"): the old spelling is refused with the file, the line and the new one."""
    p = tmp_path / "plus.yaml"
    p.write_text("tracker:\n  driver: igtl\n  host: 127.0.0.1\n  timeout_s: 1.5\n"
                 "  tools: {marker: MarkerToTracker}\n")
    with pytest.raises(ConfigError) as e:
        load_config(p)
    assert str(e.value) == (f"{p}, line 4: key 'tracker.timeout_s': moved for driver 'igtl': "
                            "write it as tracker.options.timeout_s (docs/configs.md)")


def test_a_section_gives_the_driver_its_arguments() -> None:
    s = parse()
    assert s.kwargs() == {"tools": SECTION["tools"], "host": "192.168.1.20", "port": 18945}
    assert s.address() == "192.168.1.20:18945"
    t = IGTLTracker(**s.kwargs(), frame_rate_hz=60)   # the constructor takes them as they are
    assert (t.host, t.port, t.device_names) == ("192.168.1.20", 18945, SECTION["tools"])


def test_defaults() -> None:
    s = parse(port=_DROP)
    assert s.port == 18944
    assert IGTLSettings.KEYS == ("host", "port")
    t = IGTLTracker(**s.kwargs())
    assert (t.timeout_s, t.ask_metadata) == (2.0, True)


@pytest.mark.parametrize("key, value", [
    ("host", _DROP), ("host", ""), ("host", "  "), ("host", "plus pc"), ("host", 5),
    ("port", 0), ("port", 65536), ("port", -1), ("port", "18944"), ("port", True),
    ("port", 18944.0),
])
def test_a_bad_value_names_its_key(key: str, value: Any) -> None:
    with pytest.raises(ConfigError) as e:
        parse(**{key: value})
    assert str(e.value).startswith(f"{SRC}: key 'tracker.{key}': ")


@pytest.mark.parametrize("value, why", [
    ("", "device name"), (None, "device name"), (7, "device name"),
    ("X" * 21, "at most 20"), ("MärkerToTracker", "ASCII"), ("Marker\tTo", "ASCII"),
])
def test_a_bad_device_name_names_the_tool(value: Any, why: str) -> None:
    with pytest.raises(ConfigError, match=why) as e:
        parse(tools={"marker": "MarkerToTracker", "probe": value})
    assert str(e.value).startswith(f"{SRC}: key 'tracker.tools.probe': ")


def test_a_long_name_error_says_what_plusserver_sends() -> None:
    with pytest.raises(ConfigError, match=r"sends the first 20: 'StylusTipToReference'\)"):
        parse(tools={"marker": "StylusTipToReferenceTracker"})


def test_tools_must_be_a_mapping() -> None:
    with pytest.raises(ConfigError, match="key 'tracker.tools'"):
        parse(tools=["MarkerToTracker"])


@pytest.mark.parametrize("text, host, port", [
    ("127.0.0.1:19000", "127.0.0.1", 19000),
    ("plus-pc.local", "plus-pc.local", 18945),
    ("[::1]:19001", "::1", 19001),
    ("[fe80::1]", "fe80::1", 18945),
    ("::1", "::1", 18945),
])
def test_an_address_override(text: str, host: str, port: int) -> None:
    s = parse().with_address(text)
    assert (s.host, s.port) == (host, port) and s.tools == SECTION["tools"]


@pytest.mark.parametrize("text, key", [
    ("host:", "port"), ("host:0", "port"), ("host:99999", "port"), ("host:1e3", "port"),
    ("host:²", "port"), (":18944", "host"), ("", "host"), ("[::1", "host"),
    ("[::1]x", "host"),
])
def test_a_bad_address_override_names_the_key_and_the_override(text: str, key: str) -> None:
    with pytest.raises(ConfigError) as e:
        parse().with_address(text)
    assert f"(override {text!r}): key 'tracker.{key}'" in str(e.value)
