"""Checks of config values shared by every section: each failure is one ``ConfigError`` line
naming the file and the dotted key (``"rig.yaml: key 'robot.port': …"``), with the line number
added from the YAML node tree when the text is at hand.

``check_tree`` bounds the whole document (plain JSON-like data, depth, value count);
``build`` turns one section mapping into its dataclass with per-field type checks;
``number``/``positive``/``in_range``/``xyz`` check single values; ``construct`` builds a class
from config options, naming the option it refuses.
"""

from __future__ import annotations

import inspect
import math
import re
from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import yaml

from .errors import ConfigError

__all__ = ["err", "show", "join", "check_tree", "build", "number", "coerce", "xyz", "positive",
           "in_range", "key_lines", "with_line", "construct", "MAX_DEPTH", "MAX_VALUES",
           "INT_BOUND", "check_adaptive", "check_sampling", "SETTLE_MODES",
           "check_kinematics", "KINEMATIC_ERRORS", "check_ft",
           "check_mock_ft", "FT_RESERVED_OPTIONS", "MOCK_FT_KEYS"]

MAX_DEPTH = 32
MAX_VALUES = 100_000
INT_BOUND = 2**63


def err(src: str, key: str, msg: str) -> ConfigError:
    """``ConfigError("<src>: key '<key>': <msg>")`` on one line, whatever the key holds."""
    if not key.isprintable():  # one line, whatever the key holds
        key = key.encode("unicode_escape").decode("ascii")
    return ConfigError(f"{src}: key '{key}': {' '.join(msg.splitlines())}")


def show(v: Any, limit: int = 60) -> str:
    """A short repr of a config value for messages (never raises, never huge)."""
    try:
        r = repr(v)
    except (ValueError, RecursionError):  # an int beyond the str-digits limit, deep nesting
        r = f"<{type(v).__name__}>"
    return r if len(r) <= limit else r[:limit - 1] + "…"


def join(path: str, key: str) -> str:
    """The dotted key path ``path.key`` (``key`` at the top level)."""
    return f"{path}.{key}" if path else key


def check_tree(data: Any, src: str) -> None:
    """The whole document is plain JSON-like data: string keys, finite floats, int64 ints,
    at most ``MAX_DEPTH`` deep and ``MAX_VALUES`` values (aliases counted each time they are
    used), no recursive anchors. Raises ConfigError naming the first offending key."""
    count = 0
    on_path: set[int] = set()

    def walk(v: Any, path: str, depth: int) -> None:
        nonlocal count
        count += 1
        if count > MAX_VALUES:
            raise err(src, path or "(top level)", f"the document holds more than "
                      f"{MAX_VALUES:,} values (YAML aliases expanded); a rig config is far "
                      "smaller")
        if depth > MAX_DEPTH:
            raise err(src, path, f"nested more than {MAX_DEPTH} levels deep")
        if isinstance(v, Mapping | list | tuple):
            if id(v) in on_path:
                raise err(src, path, "refers to itself (a recursive YAML anchor and alias)")
            on_path.add(id(v))
            if isinstance(v, Mapping):
                for k, x in v.items():
                    if not isinstance(k, str):
                        raise err(src, join(path, show(k)), f"every key must be a string, "
                                  f"got {type(k).__name__} {show(k)} (quote it)")
                    walk(x, join(path, k), depth + 1)
            else:
                for i, x in enumerate(v):
                    walk(x, f"{path}[{i}]", depth + 1)
            on_path.discard(id(v))
        elif v is None or isinstance(v, bool | str):
            return
        elif isinstance(v, int):
            if not -INT_BOUND <= v < INT_BOUND:
                raise err(src, path, "integer out of range (|value| ≥ 2**63)")
        elif isinstance(v, float):
            if not math.isfinite(v):
                raise err(src, path, f"{v!r} is not a finite number")
        else:
            raise err(src, path, f"unsupported value {show(v)} of type {type(v).__name__}; "
                      "expected a number, string, list or mapping (quote text)")

    walk(data, "", 0)


def build(cls: type, data: Any, src: str, section: str) -> Any:
    """Build dataclass ``cls`` from a mapping, checking keys and simple types."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise err(src, section, f"expected a mapping, got {type(data).__name__}")
    names = {f.name: f for f in fields(cls)}
    for k in data:
        if not isinstance(k, str):
            raise err(src, f"{section}.{show(k)}", "every key must be a string (quote it)")
    unknown = sorted(k for k in data if k not in names)
    if unknown:
        raise err(src, f"{section}.{unknown[0]}",
                  f"unknown key; expected one of: {', '.join(sorted(names))}")
    kwargs: dict[str, Any] = {}
    for k, v in data.items():
        f = names[k]
        kwargs[k] = coerce(v, f.type, src, f"{section}.{k}")
    try:
        return cls(**kwargs)
    except TypeError as e:
        raise err(src, section, str(e)) from None


def number(v: Any, src: str, key: str, what: str = "a number") -> float:
    """A finite real from a config value (bool, str, NaN, ±inf, overflow refused; -0.0 → 0)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise err(src, key, f"expected {what}, got {show(v)}")
    try:
        x = float(v)
    except OverflowError:
        raise err(src, key, f"expected {what}, got a number too large for a float") from None
    if not math.isfinite(x):
        raise err(src, key, f"expected {what}, got {show(v)}")
    return x + 0.0  # -0.0 → 0.0


def coerce(v: Any, typ: Any, src: str, key: str) -> Any:
    """``v`` checked against the dataclass field type ``typ`` (int, float, str, xyz point,
    list of points, mapping with string keys); None only where the type allows it."""
    t = str(typ)
    if v is None:
        if "None" in t or t in ("Any",):
            return None
        raise err(src, key, f"must not be empty (expected {t})")
    if t.startswith("int"):
        if isinstance(v, bool) or not isinstance(v, int):
            raise err(src, key, f"expected an integer, got {show(v)}")
        if not -INT_BOUND <= v < INT_BOUND:
            raise err(src, key, "integer out of range (|value| ≥ 2**63)")
        return v
    if t.startswith("float"):
        return number(v, src, key)
    if t.startswith("str"):
        if not isinstance(v, str):
            raise err(src, key, f"expected a string, got {show(v)}")
        return v
    if t.startswith("tuple[float, float, float]"):
        return xyz(v, src, key)
    if t.startswith("list[tuple[float, float, float]]"):
        if not isinstance(v, list | tuple) or not v:
            raise err(src, key, f"expected a list of [x, y, z] points in mm, got {show(v)}")
        return [xyz(p, src, f"{key}[{i}]") for i, p in enumerate(v)]
    if t.startswith("dict"):
        if not isinstance(v, Mapping):
            raise err(src, key, f"expected a mapping, got {show(v)}")
        for k in v:
            if not isinstance(k, str):
                raise err(src, f"{key}.{show(k)}", "every key must be a string (quote it)")
        return dict(v)
    return v


def xyz(v: Any, src: str, key: str) -> tuple[float, float, float]:
    """A point ``[x, y, z]`` of three finite numbers (mm)."""
    msg = f"expected a list of 3 finite numbers [x, y, z] in mm, got {show(v)}"
    if not isinstance(v, list | tuple) or len(v) != 3:
        raise err(src, key, msg)
    x, y, z = (number(c, src, key, "a list of 3 finite numbers [x, y, z] in mm") for c in v)
    return (x, y, z)


def positive(src: str, key: str, value: float, allow_zero: bool = False,
             at_most: float | None = None) -> None:
    """``value`` > 0 (≥ 0 with ``allow_zero``) and at most ``at_most`` (a larger value is a
    typo or a unit mistake), else a ConfigError naming the key."""
    if not (value > 0 or (allow_zero and value == 0)):
        raise err(src, key, f"must be {'≥' if allow_zero else '>'} 0, got {value}")
    if at_most is not None and not value <= at_most:
        raise err(src, key, f"{value} is implausibly large (at most {at_most:g}); check the "
                  "units")


def in_range(src: str, key: str, value: int, lo: int, hi: int) -> None:
    """``lo <= value <= hi``, else a ConfigError naming the key."""
    if not lo <= value <= hi:
        raise err(src, key, f"must be in {lo}…{hi}, got {value}")


def key_lines(text: str) -> dict[str, int]:
    """Dotted key path → 1-based line of the key, from the YAML node tree (best effort)."""
    out: dict[str, int] = {}
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except (yaml.YAMLError, RecursionError, ValueError):
        return out
    seen: set[int] = set()

    def walk(node: Any, path: str, depth: int) -> None:
        if depth > MAX_DEPTH or id(node) in seen or len(out) > MAX_VALUES:
            return
        seen.add(id(node))
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                if isinstance(k, yaml.ScalarNode):
                    key = join(path, str(k.value))
                    out.setdefault(key, k.start_mark.line + 1)
                    walk(v, key, depth + 1)
        elif isinstance(node, yaml.SequenceNode):
            for i, v in enumerate(node.value):
                key = f"{path}[{i}]"
                out.setdefault(key, v.start_mark.line + 1)
                walk(v, key, depth + 1)

    if root is not None:
        walk(root, "", 0)
    return out


def with_line(e: ConfigError, src: str, text: str) -> ConfigError:
    """``e`` with ", line N" after the file name when its key is found in the YAML."""
    msg = str(e)
    m = re.match(re.escape(src) + r": key '([^']*)'", msg)
    if m is None:
        return e
    lines = key_lines(text)
    key = m.group(1)
    while key and key not in lines:  # the nearest enclosing key that is in the file
        cut = max(key.rfind("."), key.rfind("["))
        key = key[:cut] if cut > 0 else ""
    if not key:
        return e
    return ConfigError(f"{src}, line {lines[key]}{msg[len(src):]}")


def construct(cls: Any, where: str, *args: Any, **options: Any) -> Any:
    """``cls(*args, **options)`` for options taken from a config: an option the class does
    not accept, or a value it rejects, raises ConfigError naming ``where`` and the option."""
    params = inspect.signature(cls).parameters
    if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        unknown = sorted(set(options) - set(params))
        if unknown:
            accepted = sorted(k for k, p in params.items()
                              if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD))
            raise ConfigError(f"{where}: unknown key {unknown[0]!r} for {cls.__name__}; "
                              f"expected one of: {', '.join(accepted)}")
    try:
        return cls(*args, **options)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {e}") from None


#: the most poses an adaptive run may take or choose among (as a plan's length)
_MAX_POOL = 100_000


def check_adaptive(a: Any, src: str) -> Any:
    """The ``adaptive`` section (an ``AdaptiveConfig``): target_mm in (0, 100] mm, confidence
    in (0, 1), 3 ≤ bootstrap ≤ max_poses ≤ pool (3 poses: the fewest that fix X, Y and Z),
    1 ≤ region ≤ pool ≤ 100,000; else a ConfigError naming the key. Returns ``a``."""
    positive(src, "adaptive.target_mm", a.target_mm, at_most=100.0)
    if not 0 < a.confidence < 1:
        raise err(src, "adaptive.confidence", f"must be in (0, 1), got {a.confidence}")
    in_range(src, "adaptive.pool", a.pool, 1, _MAX_POOL)
    from .calib.adaptive import minimum_poses  # the fewest poses that fix X, Y and Z

    least = minimum_poses(2)
    in_range(src, "adaptive.max_poses", a.max_poses, least, a.pool)
    in_range(src, "adaptive.region", a.region, 1, a.pool)
    if a.bootstrap is not None:
        in_range(src, "adaptive.bootstrap", a.bootstrap, least, a.max_poses)
    return a


#: sampling.settle: wait for stillness (bounded by settle_s) or a fixed settle_s
SETTLE_MODES = ("still", "fixed")


def check_sampling(s: Any, src: str) -> None:
    """The ``sampling`` section's ranges (a ``SamplingConfig``), each violation a ConfigError
    naming the key: counts, times and tolerances finite and in a sensible range; with
    ``sem_mm``, the floor ``min_samples`` is not above the cap ``samples``."""
    in_range(src, "sampling.samples", s.samples, 1, 1_000_000)
    positive(src, "sampling.settle_s", s.settle_s, allow_zero=True, at_most=3600.0)
    in_range(src, "sampling.robot_reads", s.robot_reads, 1, 1_000_000)
    if not 0 < s.min_share <= 1:
        raise err(src, "sampling.min_share", f"must be in (0, 1], got {s.min_share}")
    positive(src, "sampling.max_frames_factor", s.max_frames_factor, at_most=1000.0)
    if s.settle not in SETTLE_MODES:
        raise err(src, "sampling.settle", f"expected 'still' (wait until the tools are "
                  f"still, at most settle_s) or 'fixed' (wait settle_s), got {show(s.settle)}")
    positive(src, "sampling.still_window_s", s.still_window_s, at_most=60.0)
    if s.still_tol_mm is not None:
        positive(src, "sampling.still_tol_mm", s.still_tol_mm, at_most=10.0)
    in_range(src, "sampling.min_samples", s.min_samples, 1, 1_000_000)
    if s.sem_mm is not None:
        positive(src, "sampling.sem_mm", s.sem_mm, at_most=10.0)
        if s.min_samples > s.samples:
            raise err(src, "sampling.min_samples", f"{s.min_samples} is above samples "
                      f"{s.samples} (the floor of samples by need is above their cap)")


#: the error protocols of ``mock.kinematics.errors`` (its arms are the arm registry's,
#: ``tmscal.calib.kinematics.ARM_NAMES``, imported when a config names one: importing
#: ``tmscal.calib`` loads the solvers)
KINEMATIC_ERRORS = ("paper", "all", "none")


def check_kinematics(data: Any, src: str, default_seed: int) -> dict[str, Any] | None:
    """``mock.kinematics`` (None when absent): {arm: a registered arm (``tmscal.calib.
    kinematics.ARM_NAMES``: ur5e, vs060, fr3, …), errors: paper|all|none
    (default paper), seed: int (default the mock's seed)}, checked and completed; a
    ConfigError names the key."""
    if data is None:
        return None
    if not isinstance(data, Mapping):
        raise err(src, "mock.kinematics", f"expected a mapping {{arm, errors, seed}}, got "
                  f"{show(data)}")
    extra = sorted(str(k) for k in data if k not in ("arm", "errors", "seed"))
    if extra:
        raise err(src, f"mock.kinematics.{extra[0]}", "unknown key (expected arm, errors, "
                  "seed)")
    from .calib.kinematics.arms import ARM_NAMES

    arm = data.get("arm")
    if arm not in ARM_NAMES:
        raise err(src, "mock.kinematics.arm", f"expected one of {', '.join(ARM_NAMES)}, "
                  f"got {show(arm)}")
    errors = data.get("errors", "paper")
    if errors not in KINEMATIC_ERRORS:
        raise err(src, "mock.kinematics.errors", "expected one of "
                  f"{', '.join(KINEMATIC_ERRORS)}, got {show(errors)}")
    seed = data.get("seed", default_seed)
    if type(seed) is not int:
        raise err(src, "mock.kinematics.seed", f"expected an integer, got {show(seed)}")
    in_range(src, "mock.kinematics.seed", seed, 0, INT_BOUND - 1)
    return {"arm": arm, "errors": errors, "seed": seed}


#: ft.options keys that have their own key in the ft section
FT_RESERVED_OPTIONS = ("host", "port", "counts_per_force", "counts_per_torque", "samples")
#: what ``mock.ft`` may set: the sensor's noise (σ per force channel N, per torque channel
#: N·m), its faults, the ATI mock's record rate (Hz), the UR controller's payload
MOCK_FT_KEYS = ("noise_n", "noise_nm", "faults", "rate_hz", "payload_kg", "payload_cog_mm")


def check_ft(ft: Any, src: str) -> Any:
    """The ``ft`` section (an ``FTConfig``, its driver already checked): port in 0…65535,
    counts per N and per N·m > 0 and plausible when given, 1 ≤ samples ≤ 1,000,000, no
    option that has its own key; else a ConfigError naming the key. Returns ``ft``."""
    if ft.host is not None and not ft.host:
        raise err(src, "ft.host", "must not be empty (an address, or 'robot' for a sensor "
                  "in the robot arm)")
    if ft.port is not None:
        in_range(src, "ft.port", ft.port, 0, 65535)
    for key in ("counts_per_force", "counts_per_torque"):
        v = getattr(ft, key)
        if v is not None:
            positive(src, f"ft.{key}", v, at_most=1e12)
    in_range(src, "ft.samples", ft.samples, 1, 1_000_000)
    for k in ft.options:
        if k in FT_RESERVED_OPTIONS:
            raise err(src, f"ft.options.{k}", f"'{k}' cannot be set through options; set "
                      f"ft.{k} instead")
    return ft


def check_mock_ft(data: Any, src: str) -> None:
    """``mock.ft``: a mapping of ``MOCK_FT_KEYS`` (values are checked when the mock is built);
    ``faults`` a mapping."""
    if not isinstance(data, Mapping):
        raise err(src, "mock.ft", f"expected a mapping, got {show(data)}")
    extra = sorted(str(k) for k in data if k not in MOCK_FT_KEYS)
    if extra:
        raise err(src, f"mock.ft.{extra[0]}", f"unknown key (expected one of "
                  f"{', '.join(MOCK_FT_KEYS)})")
    if data.get("faults") is not None and not isinstance(data["faults"], Mapping):
        raise err(src, "mock.ft.faults", f"expected a mapping of fault settings, got "
                  f"{show(data['faults'])}")
