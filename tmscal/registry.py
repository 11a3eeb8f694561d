"""The one driver registry: driver name → ``DriverSpec`` (what kind of device it is, which
class drives it, which class reads its config keys, which mock serves it, its default port and
its pip extra). Within a kind a name is one driver; one name may serve several kinds (``sim``:
the in-process robot and tracker), so lookups take the kind the config section gives.

A ground module (it imports only ``tmscal.errors``), so every layer may ask it: the config
parser for the names valid in ``robot.driver``, ``tracker.driver`` and ``ft.driver``
(force-torque sensors) and for each driver's own settings class (``tmscal.config.devices``);
``acquisition.devices`` builds drivers from it and ``mocks.launch`` builds mocks from it, so none
of them names a brand. Classes are given as ``"module:Class"`` strings and imported only when
used, so a driver whose optional extra is missing costs nothing until a config names it, and
then is one ``MissingExtraError`` saying which extra to install.

Adding a device family is one folder (``tmscal/drivers/<name>/``: the driver and its settings
class) and one line in ``BUILTIN``, plus its protocol-level mock in ``tmscal/mocks/``
(docs/devices.md, "Adding a driver"). A third-party package registers its own through the
entry-point group ``tmscal.drivers``, each entry point giving a ``DriverSpec`` (or a function
returning one)::

    [project.entry-points."tmscal.drivers"]
    kuka = "tmscal_kuka:SPEC"

Entry points are loaded once, the first time a name is not found among the built-in drivers
or the whole list is asked for; a broken one is a ``ConfigError`` naming it.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from .errors import ConfigError, MissingExtraError

__all__ = ["DriverSpec", "BUILTIN", "ENTRY_POINT_GROUP", "KINDS", "register", "slot", "get_spec",
           "driver_names", "driver_class", "alternatives", "is_registered"]

#: the entry-point group third-party drivers register in
ENTRY_POINT_GROUP = "tmscal.drivers"
#: the device kinds a driver can be
KINDS = ("robot", "tracker", "ft")


def _import(target: str, what: str, extra: str | None) -> Any:
    """The object named by ``"module:attr"``; an ImportError is a ``MissingExtraError`` when the
    spec has an extra (else a ``ConfigError``), both naming ``what``."""
    mod, _, attr = target.partition(":")
    try:
        return getattr(importlib.import_module(mod), attr)
    except ImportError as e:
        if extra is not None:
            raise MissingExtraError(what, extra, str(e)) from e
        raise ConfigError(f"{what} cannot be loaded ({e})") from e
    except AttributeError:
        raise ConfigError(f"{what}: module {mod!r} has no {attr!r}") from None


@dataclass(frozen=True)
class DriverSpec:
    """How tmscal drives and mocks one device family.

    ``name`` is what ``robot.driver`` / ``tracker.driver`` / ``ft.driver`` says in a config;
    ``kind`` is "robot", "tracker" or "ft"; ``cls`` the driver class as ``"module:Class"`` (a
    ``Robot``, ``Tracker`` or ``ForceTorque`` subclass whose ``name`` equals ``name``).
    ``mock`` is the protocol-level mock class (``"module:Class"``, or None), ``mock_faults``
    the dataclass built from the config's ``mock.<kind>.faults`` and ``mock_volume``
    (trackers) the one built from ``mock.tracker.volume``. ``default_port`` is the port (TCP;
    UDP for ``ati``) the driver and mock take when the config gives none (None: the driver
    takes no ``port``, e.g. UR's fixed RTDE ports).
    ``extra`` is the pip extra the driver needs and ``requires`` the modules that extra
    provides (checked when the driver is loaded). ``settings`` is the class that reads and
    checks the driver's own config keys and options (``"module:Class"``, a subclass of
    ``tmscal.config.devices.DriverSettings``; None: the kind's generic settings, which check
    no key of their own and pass the options to the constructor as they are). It is imported
    when a config names the driver, so it must not need the driver's extra.
    """

    name: str
    kind: str
    cls: str
    mock: str | None = None
    mock_faults: str | None = None
    mock_volume: str | None = None
    default_port: int | None = None
    extra: str | None = None
    requires: tuple[str, ...] = ()
    settings: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise ValueError(f"DriverSpec.name must be an identifier, got {self.name!r}")
        if self.kind not in KINDS:
            raise ValueError(f"DriverSpec {self.name!r}: kind must be one of {KINDS}, got "
                             f"{self.kind!r}")
        for field in ("cls", "mock", "mock_faults", "mock_volume", "settings"):
            v = getattr(self, field)
            if v is not None and (not isinstance(v, str) or v.count(":") != 1):
                raise ValueError(f"DriverSpec {self.name!r}: {field} must be 'module:Class', "
                                 f"got {v!r}")

    def load(self) -> type:
        """The driver class. ``MissingExtraError`` when its extra (a module of ``requires``)
        is not installed; ``ConfigError`` when it cannot be imported otherwise."""
        what = f"driver {self.name!r}"
        for mod in self.requires:
            if importlib.util.find_spec(mod) is None:
                raise MissingExtraError(what, self.extra or self.name,
                                        f"no module named {mod!r}")
        return _import(self.cls, what, self.extra)

    def installed(self) -> bool:
        """Whether the modules of ``requires`` (the driver's extra) can be imported here."""
        return all(importlib.util.find_spec(mod) is not None for mod in self.requires)

    def load_settings(self) -> type | None:
        """The settings class (None: the spec names none). ``ConfigError`` when it cannot be
        imported: a settings module needs no optional extra."""
        if self.settings is None:
            return None
        return _import(self.settings, f"the {self.name!r} settings", None)

    def load_mock(self, part: str = "mock") -> type:
        """The mock class (``part="mock"``) or one of its option classes (``"mock_faults"``,
        ``"mock_volume"``); ``ConfigError`` when this driver has none."""
        target = getattr(self, part)
        if target is None:
            raise ConfigError(f"driver {self.name!r} has no {part.replace('_', ' ')}")
        return _import(target, f"the {self.name!r} {part.replace('_', ' ')}", self.extra)


#: the drivers shipped with tmscal; a new device family is one more line here
BUILTIN: tuple[DriverSpec, ...] = (
    DriverSpec("ur", "robot", "tmscal.drivers.ur.robot:URRobot", mock="tmscal.mocks.ur:URMock",
               mock_faults="tmscal.mocks.ur:URFaults", extra="ur",
               requires=("rtde_control", "rtde_receive"),
               settings="tmscal.drivers.ur.settings:URSettings"),
    DriverSpec("denso", "robot", "tmscal.drivers.denso.robot:DensoRobot",
               mock="tmscal.mocks.denso:DensoMock", mock_faults="tmscal.mocks.denso:DensoFaults",
               default_port=5007, settings="tmscal.drivers.denso.settings:DensoSettings"),
    DriverSpec("ndi", "tracker", "tmscal.drivers.ndi.tracker:NDITracker",
               mock="tmscal.mocks.polaris:PolarisMock",
               mock_faults="tmscal.mocks.polaris:PolarisFaults",
               mock_volume="tmscal.mocks.polaris:MeasurementVolume",
               settings="tmscal.drivers.ndi.settings:NDISettings"),
    DriverSpec("igtl", "tracker", "tmscal.drivers.igtl.tracker:IGTLTracker",
               mock="tmscal.mocks.igtl:IGTLTrackerMock", mock_faults="tmscal.mocks.igtl:IGTLFaults",
               mock_volume="tmscal.mocks.igtl:MeasurementVolume", default_port=18944,
               settings="tmscal.drivers.igtl.settings:IGTLSettings"),
    DriverSpec("franka", "robot", "tmscal.drivers.franka.robot:FrankaRobot",
               mock="tmscal.mocks.franka:FrankaMock",
               mock_faults="tmscal.mocks.franka:FrankaFaults", extra="franka",
               requires=("franky",), settings="tmscal.drivers.franka.settings:FrankaSettings"),
    DriverSpec("ati", "ft", "tmscal.drivers.ati.sensor:ATINetFT",
               mock="tmscal.mocks.ati:ATINetFTMock", mock_faults="tmscal.mocks.ati:ATIFaults",
               default_port=49152, settings="tmscal.drivers.ati.settings:ATISettings"),
    # the UR's built-in sensor: the UR mock serves it (ft_raw_wrench, actual_TCP_force)
    DriverSpec("ur_wrench", "ft", "tmscal.drivers.ur.wrench:URWrench",
               mock="tmscal.mocks.ur:URMock", mock_faults="tmscal.mocks.ur:URFaults",
               extra="ur", requires=("rtde_receive",),
               settings="tmscal.drivers.ur.settings:URWrenchSettings"),
    # in-process: the sim rig in this process, no wire protocol (so no mock); one name for
    # the robot and the tracker, which share a rig by channel (docs/devices.md)
    DriverSpec("sim", "robot", "tmscal.drivers.sim.robot:SimRobot",
               settings="tmscal.drivers.sim.settings:SimRobotSettings"),
    DriverSpec("sim", "tracker", "tmscal.drivers.sim.tracker:SimTracker",
               settings="tmscal.drivers.sim.settings:SimTrackerSettings"),
)

def slot(spec: DriverSpec, specs: dict[str, DriverSpec] | None = None) -> str:
    """The key of ``spec`` in ``SPECS``: its name, or ``"<name>/<kind>"`` when the name is
    held by a driver of another kind (one name may serve a robot and a tracker, as ``sim``
    does; within a kind a name is one driver)."""
    specs = SPECS if specs is None else specs
    held = specs.get(spec.name)
    return spec.name if held is None or held.kind == spec.kind else f"{spec.name}/{spec.kind}"


def _lookup(name: str, kind: str | None) -> DriverSpec | None:
    """The registered spec of ``name`` (of ``kind``, when given; else the first registered
    of that name), or None."""
    spec = SPECS.get(name)
    if kind is None or (spec is not None and spec.kind == kind):
        return spec
    return SPECS.get(f"{name}/{kind}")


#: key (``slot``) → spec, in registration order (built-ins first, then entry points)
SPECS: dict[str, DriverSpec] = {}
for _s in BUILTIN:
    SPECS[slot(_s)] = _s
_entry_points_loaded = False
_lock = threading.Lock()


def register(spec: DriverSpec, replace: bool = False) -> DriverSpec:
    """Add ``spec`` to the registry; a name already taken by a driver of its kind is a
    ``ConfigError`` unless ``replace``. Returns the spec."""
    if not isinstance(spec, DriverSpec):
        raise ConfigError(f"not a DriverSpec: {spec!r}")
    key = slot(spec)
    if key in SPECS and not replace and SPECS[key] != spec:
        raise ConfigError(f"driver {spec.name!r} is registered twice")
    SPECS[key] = spec
    return spec


def _spec_from_entry_point(ep: Any) -> DriverSpec:
    where = f"entry point {ep.name!r} = {ep.value!r} (group {ENTRY_POINT_GROUP!r})"
    try:
        obj = ep.load()
        if callable(obj) and not isinstance(obj, DriverSpec):
            obj = obj()
    except Exception as e:
        raise ConfigError(f"{where} cannot be loaded ({type(e).__name__}: {e})") from e
    if not isinstance(obj, DriverSpec):
        raise ConfigError(f"{where} gives {type(obj).__name__}, not a DriverSpec")
    if obj.name != ep.name:
        raise ConfigError(f"{where} gives the driver {obj.name!r}; the names must match")
    return obj


def _load_entry_points(entry_points: Callable[..., Iterable[Any]] | None = None) -> None:
    """Register every spec of the ``tmscal.drivers`` entry points, once."""
    global _entry_points_loaded
    with _lock:
        if _entry_points_loaded:
            return
        eps = (entry_points or importlib.metadata.entry_points)(group=ENTRY_POINT_GROUP)
        specs = [_spec_from_entry_point(ep) for ep in eps]
        for spec in specs:
            key = slot(spec)
            if key in SPECS and SPECS[key] != spec:
                raise ConfigError(f"entry point {spec.name!r} (group {ENTRY_POINT_GROUP!r}) "
                                  "reuses the name of a registered driver")
        for spec in specs:
            SPECS[slot(spec)] = spec
        _entry_points_loaded = True


def driver_names(kind: str | None = None) -> list[str]:
    """Every registered driver name (entry points included), in registration order; only
    those of ``kind`` ("robot", "tracker" or "ft") when given."""
    _load_entry_points()
    names = [s.name for s in SPECS.values() if kind is None or s.kind == kind]
    return list(dict.fromkeys(names))


def is_registered(name: str, kind: str | None = None) -> bool:
    """True when ``name`` is registered (of ``kind``, when given). Entry points are loaded
    only when the name is not among the drivers registered so far."""
    if _lookup(name, kind) is None:
        driver_names()
    return _lookup(name, kind) is not None


def alternatives(names: Iterable[str]) -> str:
    """``'a', 'b' or 'c'`` for messages."""
    q = [repr(n) for n in names]
    return " or ".join([", ".join(q[:-1]), q[-1]]) if len(q) > 1 else "".join(q)


def get_spec(name: str, kind: str | None = None) -> DriverSpec:
    """The spec registered under ``name`` (of ``kind``, when given; without it the first
    registered of that name). An unknown name (or one of another ``kind``) is a
    ``ConfigError`` listing the known ones."""
    spec = _lookup(name, kind)
    if spec is None:
        _load_entry_points()
        spec = _lookup(name, kind)
    if spec is None:
        known = ", ".join(sorted(driver_names(kind)))
        label = "driver" if kind is None else f"{kind} driver"
        raise ConfigError(f"unknown {label} {name!r}; known {label}s: {known}")
    return spec


def driver_class(name: str, kind: str | None = None) -> type:
    """The driver class registered under ``name`` (of ``kind``, when given: ``sim`` is a
    robot and a tracker; without it, the first registered); unknown names raise
    ``ConfigError`` listing the known ones, a missing extra ``MissingExtraError``."""
    return get_spec(name, kind).load()
