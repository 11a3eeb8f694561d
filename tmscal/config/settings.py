"""The settings protocol: how a driver declares, reads and checks its own config keys.

A config section names a driver (``tracker: {driver: ndi, ...}``). The keys every device of
its kind has are generic and read by :mod:`tmscal.config.devices`:

* tracker: ``driver``, ``tools`` (tool name → a value the driver knows the tool by),
  ``frame_rate_hz`` (Hz), ``options``;
* robot: ``driver``, ``host``, ``port``, ``speed_mm_s`` (mm/s), ``accel_mm_s2`` (mm/s²),
  ``options``;
* ft: ``driver``, ``host``, ``port``, ``samples``, ``options``.

Everything else belongs to the driver. Its spec in the driver registry names a settings class
(``DriverSpec(..., settings="tmscal.drivers.ndi.settings:NDISettings")``), a frozen dataclass
subclassing :class:`DriverSettings` (trackers: :class:`TrackerSettings`) that declares:

* ``KEYS``: the section keys the driver owns beside the generic ones (NDI: ``port``,
  ``baud``, ``reply``, ``log_wire``), each a dataclass field whose type (bool, int, float,
  str, optionally ``| None``) is checked when the section is read;
* ``OPTIONS``: ``{name: Option(...)}``, the ``<kind>.options`` the driver accepts, each with
  its type, range, default, unit and help, declared once (None: no declaration, the
  constructor decides when the driver is built). The driver's constructor takes its
  defaults from here (``defaults()``) and checks its keyword arguments with
  ``check_options`` against the same declaration, so no range is written twice; the option
  tables of docs/configs.md are rendered from it (:mod:`tmscal.config.doc`);
* ``MOVED`` (optional): ``{old spelling: new spelling}`` of keys and options that moved
  (``"timeout_s": "options.timeout_s"``), each relative to the section: a config that still
  uses the old one is refused naming the new one;
* ``parse(section, src, base_dir, check_files)``: the settings from the whole section
  mapping (generic keys already checked): the driver's keys and, for a tracker, the tools'
  values, every problem a ``ConfigError`` made by ``err(src, "<kind>.<key>", ...)`` so that
  ``load_config`` adds the line number;
* ``kwargs()``: the driver constructor's keyword arguments from these settings (a tracker's
  include ``tools``); it may raise ``ConfigError`` for what matters only when a driver is
  built (NDI: no port given, a ROM file that is not there);
* ``address()`` and ``with_address(text)``: where the device is (NDI: the serial device or
  ``socket://`` URL) and a copy at another address (the command line's ``--tracker-port``),
  checked as ``parse`` checks it; ``ADDRESS_KEY`` is the key ``address()`` comes from, for
  messages;
* ``mock_kwargs()`` (optional): what the driver's mock must know from these settings (ATI:
  the counts per unit its records are scaled by);
* a tracker's ``FRAME_RATE_HZ`` (optional): the frame rates (Hz, inclusive) its devices can
  run at, with ``FRAME_RATE_DEVICES`` naming them; ``tracker.frame_rate_hz`` outside is
  refused when the config is read;
* a tracker's ``preflight()`` (optional): the checks of ``tmscal acquire --dry-run`` that
  need no device but more than ``parse`` does (NDI: the ROM files' contents), one line per
  thing checked, a ``ConfigError`` naming the key for a problem.

An unknown key in a section is refused naming it and the keys the driver accepts; an option
may not name a generic key or one of ``KEYS`` (they have their own keys). docs/devices.md,
"Adding a driver", walks through one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Self

from ..errors import ConfigError
from .values import build, err, number, show

__all__ = ["Option", "DriverSettings", "TrackerSettings", "RobotSettings", "FTSettings"]


def _n(v: float) -> str:
    """A bound for messages: 3600000, not 3.6e+06."""
    return str(int(v)) if float(v).is_integer() else f"{v:g}"


@dataclass(frozen=True)
class Option:
    """One driver option (``<kind>.options.<name>``): its ``type`` (bool, int, float or
    str), inclusive bounds ``lo``/``hi`` and exclusive bounds ``above``/``below`` (numbers,
    in the option's ``unit``), the ``choices`` a string may take, whether null is allowed
    (``null``), the ``default`` the driver takes when the option is not given, and for the
    docs ``help`` (what the option does) and ``default_text`` (how to show the default,
    when its value alone does not say it: "null: the controller's")."""

    type: type
    lo: float | None = None
    hi: float | None = None
    above: float | None = None
    below: float | None = None
    choices: tuple[str, ...] = ()
    null: bool = False
    default: Any = None
    unit: str = ""
    help: str = ""
    default_text: str = ""

    def describe(self) -> str:
        """What the option takes, for messages and docs ("a number > 0", "true or false")."""
        if self.type is bool:
            text = "true or false"
        elif self.choices:
            text = " or ".join(repr(c) for c in self.choices)
        elif self.type is str:
            text = "a string"
        else:
            text = "an integer" if self.type is int else "a number"
            bounds = [f"{op} {_n(v)}" for op, v in (("≥", self.lo), (">", self.above),
                                                  ("≤", self.hi), ("<", self.below))
                      if v is not None]
            if self.lo is not None and self.hi is not None and len(bounds) == 2:
                bounds = [f"in {_n(self.lo)}…{_n(self.hi)}"]
            if bounds:
                text += " " + " and ".join(bounds)
        return text + (" or null" if self.null else "")

    def check(self, v: Any, src: str, key: str) -> Any:
        """``v`` if it is what the option takes (a float for a number option), else a
        ConfigError naming ``key``."""
        bad = err(src, key, f"expected {self.describe()}, got {show(v)}")
        if v is None:
            if self.null:
                return None
            raise bad
        if self.type is bool or self.type is str:
            if not isinstance(v, self.type) or (self.choices and v not in self.choices):
                raise bad
            return v
        if self.type is int:
            if isinstance(v, bool) or not isinstance(v, int):
                raise bad
            x: float = v
        else:
            x = number(v, src, key, self.describe())
        if ((self.above is not None and not x > self.above)
                or (self.below is not None and not x < self.below)
                or (self.lo is not None and not x >= self.lo)
                or (self.hi is not None and not x <= self.hi)):
            raise bad
        return x

    def validate(self, v: Any, who: str, name: str) -> Any:
        """As ``check``, for a driver's keyword argument: ``v`` (a float for a number
        option), else ValueError naming ``who`` (the driver class) and ``name``."""
        try:
            return self.check(v, who, name)
        except ConfigError as e:
            raise ValueError(f"{who}: {name}: {str(e).split(': ', 2)[-1]}") from None


@dataclass(frozen=True)
class DriverSettings:
    """A driver's own config keys, read from its section (the protocol above). The base
    class reads ``KEYS`` by their field types and has no address; ``src`` is the config the
    settings came from (for messages)."""

    #: the section: "tracker", "robot" or "ft"
    SECTION: ClassVar[str] = ""
    #: the section keys the driver owns beside the generic ones (each a dataclass field)
    KEYS: ClassVar[tuple[str, ...]] = ()
    #: the options the driver accepts, name → Option (None: the constructor decides)
    OPTIONS: ClassVar[Mapping[str, Option] | None] = None
    #: the key ``address()`` is read from ("" when the address is not the driver's key)
    ADDRESS_KEY: ClassVar[str] = ""
    #: keys and options that moved, old spelling → new, both relative to the section
    #: (``"options.options": "options.reply_options"``); the old one is refused naming the new
    MOVED: ClassVar[Mapping[str, str]] = {}

    src: str = field(default="<config>", kw_only=True, compare=False)

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Each declared option's default (the driver constructor's keyword defaults)."""
        return {k: o.default for k, o in (cls.OPTIONS or {}).items()}

    @classmethod
    def check_options(cls, who: str, **values: Any) -> dict[str, Any]:
        """``values`` (a driver's keyword arguments named as its options) checked against
        ``OPTIONS``, the one declaration of their types and ranges: the checked values (a
        float for a number option), or ValueError naming ``who`` and the option."""
        declared = cls.OPTIONS or {}
        unknown = sorted(set(values) - set(declared))
        if unknown:
            raise ValueError(f"{who}: {unknown[0]!r} is not an option of {cls.__name__}")
        return {k: declared[k].validate(v, who, k) for k, v in values.items()}

    @classmethod
    def parse(cls, section: Mapping[str, Any], src: str, base_dir: Path | None,
              check_files: bool) -> Self:
        """The settings of ``section`` (the whole section mapping, its generic keys checked):
        each of ``KEYS`` given is checked against its field's type. ``base_dir`` is the
        config's folder (relative paths are resolved against it; None: as given);
        ``check_files`` False skips checks that files exist. ConfigError names the key."""
        own = {k: section[k] for k in cls.KEYS if k in section}
        return dataclasses.replace(build(cls, own, src, cls.SECTION), src=src)

    def kwargs(self) -> dict[str, Any]:
        """The driver constructor's keyword arguments from these settings: each of
        ``KEYS``."""
        return {k: getattr(self, k) for k in self.KEYS}

    def address(self) -> str:
        """Where the device is, for messages and mocks ("": not a key of the driver's)."""
        return ""

    def with_address(self, text: str) -> Self:
        """These settings at address ``text``, checked as ``parse`` checks it. The base class
        has no address key of its own: ConfigError."""
        raise self.err(self.ADDRESS_KEY or "driver",
                       f"{show(text)}: this driver takes no address override")

    def mock_kwargs(self) -> dict[str, Any]:
        """What the driver's mock must know from these settings (default: nothing)."""
        return {}

    def err(self, key: str, msg: str) -> ConfigError:
        """``ConfigError`` naming ``<SECTION>.<key>`` of the config these settings came
        from."""
        return err(self.src, f"{self.SECTION}.{key}" if key else self.SECTION, msg)


@dataclass(frozen=True)
class TrackerSettings(DriverSettings):
    """A tracker driver's settings: ``tools`` holds each tool's value as the driver takes
    it (``parse_tool``; the base class keeps what the config gives) and goes to the
    constructor with the ``KEYS``."""

    SECTION: ClassVar[str] = "tracker"
    #: the frame rates (Hz, inclusive) the driver's devices run at (None: any the generic
    #: check allows, 0 < f ≤ 10000), and the devices that range is of, for messages
    FRAME_RATE_HZ: ClassVar[tuple[float, float] | None] = None
    FRAME_RATE_DEVICES: ClassVar[str] = ""

    tools: dict[str, Any] = field(default_factory=dict, kw_only=True)

    @classmethod
    def parse(cls, section: Mapping[str, Any], src: str, base_dir: Path | None,
              check_files: bool) -> Self:
        """As ``DriverSettings.parse``, and each tool's value through ``parse_tool``."""
        s = super().parse(section, src, base_dir, check_files)
        tools = {name: cls.parse_tool(name, v, src, base_dir, check_files)
                 for name, v in (section.get("tools") or {}).items()}
        return dataclasses.replace(s, tools=tools)

    @classmethod
    def parse_tool(cls, name: str, value: Any, src: str, base_dir: Path | None,
                   check_files: bool) -> Any:
        """Tool ``name``'s value as the driver takes it (ConfigError naming
        ``tracker.tools.<name>``). The base class takes any plain value as it is."""
        return value

    def kwargs(self) -> dict[str, Any]:
        """``tools`` and each of ``KEYS``."""
        return {"tools": dict(self.tools), **super().kwargs()}

    def preflight(self) -> list[str]:
        """The offline checks of a dry run beyond ``parse``'s (no device is opened): one
        line per thing checked; ``ConfigError`` naming the key for a problem. The base class
        checks nothing more."""
        return []


@dataclass(frozen=True)
class RobotSettings(DriverSettings):
    """A robot driver's settings. A robot's address is the generic ``host`` and ``port``
    (``acquisition.devices.make_robot`` takes their overrides), so the base class has none."""

    SECTION: ClassVar[str] = "robot"


@dataclass(frozen=True)
class FTSettings(DriverSettings):
    """A force-torque sensor driver's settings; its address is the generic ``host`` and
    ``port`` (``acquisition.devices.make_ft`` takes their overrides)."""

    SECTION: ClassVar[str] = "ft"
