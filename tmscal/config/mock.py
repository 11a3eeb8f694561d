"""The ``mock`` section: the simulated rig behind the mock devices (clock, seed, truth, noise,
settling, the serial arm of ``mock.kinematics``, what moved since the calibration
(``mock.changes``) and moves during a run (``mock.events``)) and each mock device's options
and faults (``mock.tracker``, ``mock.robot``, ``mock.ft``). Poses are 4×4 in mm; only
``tmscal mock``, ``tmscal demo`` and the tests read this section."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from .plan import pose_from_config
from .sections import MockConfig
from .values import INT_BOUND, build, construct, err, in_range, number, show

__all__ = ["KINEMATIC_ERRORS", "MOCK_FT_KEYS", "CHANGE_MM_BOUND", "CHANGE_DEG_BOUND",
           "EVENT_AT_S_BOUND", "MAX_EVENTS", "parse_mock", "check_kinematics",
           "check_mock_ft", "check_changes", "check_events"]


#: the error protocols of ``mock.kinematics.errors``, ``tmscal.sim.arm.ERROR_PROTOCOLS`` (its
#: arms are the arm registry's, ``tmscal.calib.kinematics.ARM_NAMES``, imported when a config
#: names one: importing ``tmscal.calib`` loads the solvers)
KINEMATIC_ERRORS = ("paper", "all", "none", "realistic")


def check_kinematics(data: Any, src: str, default_seed: int) -> dict[str, Any] | None:
    """``mock.kinematics`` (None when absent): {arm: a registered arm (``tmscal.calib.
    kinematics.ARM_NAMES``: ur5e, vs060, fr3, …), errors: paper|all|none|realistic
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
    from ..calib.kinematics.arms import ARM_NAMES

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


#: bounds of a change (``mock.changes``, ``mock.events``): |mm| per component (mm), |deg| per
#: component and ‖deg‖, the rotation angle (degrees); an event's time (s); how many events
CHANGE_MM_BOUND = 1000.0
CHANGE_DEG_BOUND = 180.0
EVENT_AT_S_BOUND = 1e6
MAX_EVENTS = 1000


def _triple(data: Any, src: str, key: str, bound: float, unit: str) -> list[float]:
    """Three finite numbers of magnitude ≤ ``bound``, else a ConfigError naming ``key``."""
    what = f"a list of 3 finite numbers in {unit}"
    if not isinstance(data, list | tuple) or len(data) != 3:
        raise err(src, key, f"expected {what}, got {show(data)}")
    out = [number(v, src, key, what) for v in data]
    if not all(abs(v) <= bound for v in out):
        raise err(src, key, f"each entry must be within ±{bound:g} {unit}, got {show(data)}")
    return out


def _change(data: Any, src: str, key: str, keys: tuple[str, ...]) -> dict[str, list[float]]:
    """``{mm, deg}`` of one change (each optional, default zeros; ``keys`` the other keys the
    mapping may hold, checked by the caller): mm within ±CHANGE_MM_BOUND, deg within
    ±CHANGE_DEG_BOUND per component and ‖deg‖ (the rotation angle) at most that too."""
    if not isinstance(data, Mapping):
        raise err(src, key, f"expected a mapping {{{', '.join((*keys, 'mm', 'deg'))}}}, got "
                  f"{show(data)}")
    allowed = (*keys, "mm", "deg")
    extra = sorted(str(k) for k in data if k not in allowed)
    if extra:
        raise err(src, f"{key}.{extra[0]}", f"unknown key (expected {', '.join(allowed)})")
    mm = _triple(data.get("mm", [0.0] * 3), src, f"{key}.mm", CHANGE_MM_BOUND, "mm")
    deg = _triple(data.get("deg", [0.0] * 3), src, f"{key}.deg", CHANGE_DEG_BOUND, "deg")
    if sum(v * v for v in deg) > CHANGE_DEG_BOUND ** 2:
        raise err(src, f"{key}.deg", f"the rotation angle ‖deg‖ must be at most "
                  f"{CHANGE_DEG_BOUND:g}°, got {show(deg)}")
    return {"mm": mm, "deg": deg}


def check_changes(data: Any, src: str) -> dict[str, dict[str, list[float]]]:
    """``mock.changes`` (empty when absent or null): {move: {mm: [3] mm, deg: [3] degrees}},
    move one of ``tmscal.sim.changes.MOVES``, every entry optional and ``mm``, ``deg`` each
    optional (zeros); checked, a ConfigError names the key."""
    from ..sim.changes import MOVES  # here, not at the top: importing tmscal.sim loads its arms

    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise err(src, "mock.changes", f"expected a mapping of {', '.join(MOVES)}, got "
                  f"{show(data)}")
    out: dict[str, dict[str, list[float]]] = {}
    for k, v in data.items():
        if k not in MOVES:
            raise err(src, f"mock.changes.{show(k) if not isinstance(k, str) else k}",
                      f"unknown key (expected {', '.join(MOVES)})")
        out[k] = _change(v, src, f"mock.changes.{k}", ())
    return out


def check_events(data: Any, src: str) -> list[dict[str, Any]]:
    """``mock.events`` (empty when absent or null): at most ``MAX_EVENTS`` of {at_s: seconds
    0…EVENT_AT_S_BOUND of the rig's clock, move: one of ``MOVES``, mm, deg: as in
    ``mock.changes``}; checked, a ConfigError names the key (``mock.events[1].move``)."""
    from ..sim.changes import MOVES

    if data is None:
        return []
    if not isinstance(data, list | tuple):
        raise err(src, "mock.events", f"expected a list of {{at_s, move, mm, deg}}, got "
                  f"{show(data)}")
    if len(data) > MAX_EVENTS:
        raise err(src, "mock.events", f"at most {MAX_EVENTS} events, got {len(data)}")
    out: list[dict[str, Any]] = []
    for i, e in enumerate(data):
        key = f"mock.events[{i}]"
        ch = _change(e, src, key, ("at_s", "move"))
        if "at_s" not in e:
            raise err(src, f"{key}.at_s", "missing (seconds of the rig's clock, ≥ 0)")
        at = number(e["at_s"], src, f"{key}.at_s", "a number of seconds")
        if not 0 <= at <= EVENT_AT_S_BOUND:
            raise err(src, f"{key}.at_s", f"must be in 0…{EVENT_AT_S_BOUND:g} s, got {show(at)}")
        move = e.get("move")
        if move not in MOVES:
            raise err(src, f"{key}.move", f"expected one of {', '.join(MOVES)}, got "
                      f"{show(move)}")
        out.append({"at_s": at, "move": move, **ch})
    return out


#: what ``mock.ft`` may set: the sensor's noise (σ per force channel N, per torque channel
#: N·m), its faults, the ATI mock's record rate (Hz), the UR controller's payload
MOCK_FT_KEYS = ("noise_n", "noise_nm", "faults", "rate_hz", "payload_kg", "payload_cog_mm")


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


def parse_mock(data: Any, src: str) -> MockConfig | None:
    """The mock section (None when absent): clock, seed, truth, settle (checked by building
    ``sim.Settle``), changes and events (``check_changes``, ``check_events``), per-device
    faults and the tracker's measurement volume."""
    if data is None:
        return None
    mock = build(MockConfig, data, src, "mock")
    if mock.clock not in ("fast", "real"):
        raise err(src, "mock.clock", f"expected 'fast' or 'real', got {mock.clock!r}")
    in_range(src, "mock.seed", mock.seed, 0, INT_BOUND - 1)
    if isinstance(mock.truth, Mapping):
        extra = sorted(set(mock.truth) - {"X", "Y", "Z"})
        if extra:
            raise err(src, f"mock.truth.{extra[0]}", "expected X, Y and Z only")
        mock.truth = {k: pose_from_config(v, src, f"mock.truth.{k}")
                      for k, v in mock.truth.items()}
        if "X" not in mock.truth or "Z" not in mock.truth:
            raise err(src, "mock.truth", "explicit truth needs at least X and Z")
    elif mock.truth not in ("tms", "random"):
        raise err(src, "mock.truth", f"expected 'tms', 'random' or {{X, Y, Z}}, "
                  f"got {show(mock.truth)}")
    mock.kinematics = check_kinematics(mock.kinematics, src, mock.seed)
    if mock.settle is not None:
        from ..sim.rig import Settle
        construct(Settle, f"{src}: key 'mock.settle'", **mock.settle)
    check_mock_ft(mock.ft, src)
    mock.changes = check_changes(mock.changes, src)
    mock.events = check_events(mock.events, src)
    for dev in ("tracker", "robot"):
        faults = getattr(mock, dev).get("faults")
        if faults is not None and not isinstance(faults, Mapping):
            raise err(src, f"mock.{dev}.faults", f"expected a mapping of fault settings, "
                      f"got {show(faults)}")
        vol = getattr(mock, dev).get("volume", "default")
        if dev == "tracker" and not (vol is None or vol == "default" or isinstance(vol, Mapping)):
            raise err(src, "mock.tracker.volume", f"expected 'default', null or a mapping, "
                      f"got {show(vol)}")
    return mock
