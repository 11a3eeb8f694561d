"""The device sections, ``robot``, ``tracker`` and ``ft``: their generic keys, and the call
into each driver's own settings class (:mod:`tmscal.config.settings`) for the rest.

The driver registry (:mod:`tmscal.registry`) says which drivers exist and which settings
class reads each one's keys, so nothing here names a brand. Every problem is a ConfigError
naming the file and the key (``load_config`` adds the line):

* ``<kind>.driver`` is a registered driver of that kind;
* every key of the section is a generic key of its kind or one of the driver's ``KEYS``; an
  unknown one is refused naming it and the keys the driver accepts;
* ``<kind>.options`` name none of the generic keys, the driver's keys or the arguments the
  safety section fills (``envelope``, ``speed_mm_s``, ``accel_mm_s2``), and each is one the
  driver's ``OPTIONS`` declares, of the type and range declared.

Units: speeds mm/s, accelerations mm/s², rates Hz.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .. import registry
from ..errors import ConfigError
from .sections import FTConfig, RobotConfig, TrackerConfig
from .settings import DriverSettings, FTSettings, RobotSettings, TrackerSettings
from .values import build, coerce, err, in_range, number, positive, show

__all__ = ["GENERIC_KEYS", "RESERVED_OPTIONS", "reserved_options", "settings_class",
           "check_driver", "parse_robot", "parse_tracker", "parse_ft"]

#: the keys every device of a kind has (the rest of a section is its driver's)
GENERIC_KEYS: dict[str, tuple[str, ...]] = {
    "robot": ("driver", "host", "port", "speed_mm_s", "accel_mm_s2", "arm", "urdf_base",
              "urdf_flange", "options"),
    "tracker": ("driver", "tools", "frame_rate_hz", "options"),
    "ft": ("driver", "host", "port", "samples", "options"),
}
#: constructor arguments that come from a generic key or the safety section, never options
RESERVED_OPTIONS: dict[str, tuple[str, ...]] = {
    "robot": ("envelope", "speed_mm_s", "accel_mm_s2", "host", "port"),
    "tracker": ("tools", "frame_rate_hz"),
    "ft": ("host", "port", "samples"),
}
#: the settings of a driver whose spec names none: no keys of its own, options unchecked
_DEFAULT_SETTINGS: dict[str, type[DriverSettings]] = {
    "robot": RobotSettings, "tracker": TrackerSettings, "ft": FTSettings}


def check_driver(src: str, kind: str, name: Any) -> None:
    """``name`` is a registered driver of ``kind`` (the driver registry is the one list)."""
    if not isinstance(name, str):
        raise err(src, f"{kind}.driver", f"expected a string, got {show(name)}")
    if registry.is_registered(name, kind):  # built-ins need no entry point loaded
        return
    known = registry.driver_names(kind)
    if name not in known:
        raise err(src, f"{kind}.driver", f"expected {registry.alternatives(known)}, got "
                  f"{name!r}")


def settings_class(kind: str, driver: str) -> type[DriverSettings]:
    """The settings class of registered driver ``driver`` of ``kind`` (its spec's, else the
    kind's generic one). ConfigError when the spec's cannot be loaded or is not a settings
    class of that kind."""
    spec = registry.get_spec(driver, kind)
    cls = spec.load_settings()
    base = _DEFAULT_SETTINGS[kind]
    if cls is None:
        return base
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise ConfigError(f"driver {driver!r}: settings {spec.settings!r} is not a "
                          f"{base.__name__} (tmscal.config.settings)")
    return cls


def reserved_options(kind: str,
                     settings: type[DriverSettings] | DriverSettings | None) -> tuple[str, ...]:
    """The option names a ``kind`` driver with these settings cannot take through
    ``<kind>.options``: the generic constructor arguments and the driver's ``KEYS``."""
    return RESERVED_OPTIONS[kind] + (tuple(settings.KEYS) if settings is not None else ())


def _driver_of(data: Any, src: str, kind: str,
               default: str | None = None) -> tuple[str, type[DriverSettings]]:
    """The section's driver and its settings class; a key that is neither generic nor the
    driver's is refused, naming the keys the driver accepts."""
    if not isinstance(data, Mapping):
        raise err(src, kind, f"expected a mapping, got {type(data).__name__}")
    for k in data:
        if not isinstance(k, str):
            raise err(src, f"{kind}.{show(k)}", "every key must be a string (quote it)")
    driver = data.get("driver", default)
    if driver is None:
        raise err(src, f"{kind}.driver", "missing: name a registered driver "
                  f"({registry.alternatives(registry.driver_names(kind))})")
    check_driver(src, kind, driver)
    try:
        cls = settings_class(kind, driver)
    except ConfigError as e:
        raise err(src, f"{kind}.driver", str(e)) from None
    _moved(data, src, kind, driver, cls)
    accepted = GENERIC_KEYS[kind] + tuple(cls.KEYS)
    unknown = sorted(k for k in data if k not in accepted)
    if unknown:
        raise err(src, f"{kind}.{unknown[0]}", f"unknown key for driver {driver!r}; expected "
                  f"one of: {', '.join(sorted(accepted))}")
    return driver, cls


def _moved(data: Mapping[str, Any], src: str, kind: str, driver: str,
           cls: type[DriverSettings]) -> None:
    """A key or option of the section that the driver's ``MOVED`` says has moved is refused,
    naming its new spelling (``key 'tracker.timeout_s': moved: write it as
    tracker.options.timeout_s``)."""
    options = data.get("options")
    for old, new in cls.MOVED.items():
        head, _, rest = old.partition(".")
        here = (rest in options if head == "options" and isinstance(options, Mapping)
                else not rest and head in data)
        if here:
            raise err(src, f"{kind}.{old}", f"moved for driver {driver!r}: write it as "
                      f"{kind}.{new} (docs/configs.md)")


def _options(data: Mapping[str, Any], src: str, kind: str, driver: str,
             cls: type[DriverSettings]) -> dict[str, Any]:
    """``<kind>.options``: no reserved name, each declared by the driver's ``OPTIONS`` and
    of its type and range (every option passes when the driver declares none)."""
    options = coerce(data.get("options", {}), "dict[str, Any]", src, f"{kind}.options")
    for k in options:
        if k in reserved_options(kind, cls):
            raise err(src, f"{kind}.options.{k}", f"'{k}' cannot be set through options: "
                      + ("the envelope comes from the safety section only" if k == "envelope"
                         else f"set {kind}.{k} instead"))
    declared = cls.OPTIONS
    if declared is None:
        return options
    for k in options:
        if k not in declared:
            accepted = (f"expected one of: {', '.join(sorted(declared))}" if declared
                        else "it takes no options")
            raise err(src, f"{kind}.options", f"unknown key {k!r} for driver {driver!r}; "
                      f"{accepted}")
    return {k: declared[k].check(v, src, f"{kind}.options.{k}") for k, v in options.items()}


def _generic(cls: type, data: Mapping[str, Any], src: str, kind: str) -> Any:
    """The section's generic keys but ``options`` as dataclass ``cls`` (types checked)."""
    keys = [k for k in GENERIC_KEYS[kind] if k != "options"]
    return build(cls, {k: data[k] for k in keys if k in data}, src, kind)


def parse_robot(data: Any, src: str, base_dir: Path | None = None,
                check_files: bool = True) -> RobotConfig | None:
    """The robot section (None when absent): a registered robot driver, a host, a port in
    0…65535, positive speed (mm/s) and acceleration (mm/s²), the driver's options and
    settings (``base_dir``, ``check_files``: as for ``parse_tracker``)."""
    if data is None:
        return None
    driver, cls = _driver_of(data, src, "robot")
    robot = _generic(RobotConfig, data, src, "robot")
    if not robot.host:
        raise err(src, "robot.host", "must not be empty")
    if robot.port is not None:
        in_range(src, "robot.port", robot.port, 0, 65535)
    positive(src, "robot.speed_mm_s", robot.speed_mm_s)
    positive(src, "robot.accel_mm_s2", robot.accel_mm_s2)
    _check_arm(robot, src, base_dir, check_files)
    robot.options = _options(data, src, "robot", driver, cls)
    robot.settings = cls.parse(data, src, base_dir, check_files)
    return robot


#: what makes ``robot.arm`` a path rather than a name
_ARM_SUFFIXES = (".urdf", ".yaml", ".yml", ".json")


def _check_arm(robot: RobotConfig, src: str, base_dir: Path | None, check_files: bool) -> None:
    """``robot.arm``: a short name, or a path (a suffix of :data:`_ARM_SUFFIXES` or a
    slash) made absolute against ``base_dir`` and, with ``check_files``, a file that exists;
    ``urdf_base``/``urdf_flange`` only with a URDF. The file itself is read by the
    acquisition (tmscal.formats.armdef), which names the config's key when it is not an
    arm."""
    arm = robot.arm
    if arm is not None:
        if not arm or not arm.isprintable() or len(arm) > 4096:
            raise err(src, "robot.arm", "expected an arm's name or the path of a URDF or arm "
                      "file")
        if "/" in arm or arm.lower().endswith(_ARM_SUFFIXES):
            p = Path(arm).expanduser()
            if not p.is_absolute() and base_dir is not None:
                p = base_dir / p
            if check_files and not p.is_file():
                raise err(src, "robot.arm", f"no such file: {p}")
            robot.arm = str(p)
    for k in ("urdf_base", "urdf_flange"):
        v = getattr(robot, k)
        if v is not None and (robot.arm is None or not robot.arm.lower().endswith(".urdf")):
            raise err(src, f"robot.{k}", "goes with a URDF robot.arm (a .urdf file)")
        if v is not None and (not v or len(v) > 200 or not v.isprintable()):
            raise err(src, f"robot.{k}", "expected a link's name")


def parse_tracker(data: Any, src: str, base_dir: Path | None,
                  check_files: bool = True) -> TrackerConfig | None:
    """The tracker section (None when absent): a registered tracker driver (default
    ``ndi``), at least one tool, a plausible frame rate (Hz), the driver's options, and its
    settings: its own keys and the tools' values (relative paths against ``base_dir``; that
    files exist is checked unless ``check_files`` is False, as for a command that opens
    only the robot)."""
    if data is None:
        return None
    driver, cls = _driver_of(data, src, "tracker", default="ndi")
    rate = number(data.get("frame_rate_hz", 60.0), src, "tracker.frame_rate_hz")
    positive(src, "tracker.frame_rate_hz", rate, at_most=10_000)
    tools = data.get("tools")
    if tools is not None:
        tools = coerce(tools, "dict[str, Any]", src, "tracker.tools")
    if not tools:
        raise err(src, "tracker.tools", "name at least one tool (our name → what the driver "
                  "knows it by, e.g. {marker: marker.rom} for an NDI tracker)")
    if issubclass(cls, TrackerSettings) and cls.FRAME_RATE_HZ is not None:
        lo, hi = cls.FRAME_RATE_HZ
        if not lo <= rate <= hi:
            raise err(src, "tracker.frame_rate_hz", f"{rate:g} Hz is outside the frame rates "
                      f"of the {driver} driver's devices, {lo:g}…{hi:g} Hz"
                      + (f" ({cls.FRAME_RATE_DEVICES})" if cls.FRAME_RATE_DEVICES else ""))
    options = _options(data, src, "tracker", driver, cls)
    settings = cls.parse(data, src, base_dir, check_files)
    assert isinstance(settings, TrackerSettings)
    return TrackerConfig(driver=driver, settings=settings, frame_rate_hz=rate, options=options)


def parse_ft(data: Any, src: str, base_dir: Path | None,
             check_files: bool = True) -> FTConfig | None:
    """The ``ft`` section (None when absent): a registered force-torque driver, a host
    (an address, or "robot" for a sensor in the arm), a port in 0…65535, 1 ≤ samples ≤
    1,000,000, the driver's options and settings (the Net F/T: its counts per unit)."""
    if data is None:
        return None
    driver, cls = _driver_of(data, src, "ft")
    ft = _generic(FTConfig, data, src, "ft")
    if ft.host is not None and not ft.host:
        raise err(src, "ft.host", "must not be empty (an address, or 'robot' for a sensor "
                  "in the robot arm)")
    if ft.port is not None:
        in_range(src, "ft.port", ft.port, 0, 65535)
    in_range(src, "ft.samples", ft.samples, 1, 1_000_000)
    ft.options = _options(data, src, "ft", driver, cls)
    ft.settings = cls.parse(data, src, base_dir, check_files)
    return ft
