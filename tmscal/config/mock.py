"""The ``mock`` section: the simulated rig behind the mock devices (clock, seed, truth, noise,
settling, the serial arm of ``mock.kinematics``) and each mock device's options and faults
(``mock.tracker``, ``mock.robot``, ``mock.ft``). Poses are 4×4 in mm; only ``tmscal mock``,
``tmscal demo`` and the tests read this section."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from .plan import pose_from_config
from .sections import MockConfig
from .values import INT_BOUND, build, construct, err, in_range, show

__all__ = ["KINEMATIC_ERRORS", "MOCK_FT_KEYS", "parse_mock",
           "check_kinematics", "check_mock_ft"]


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
    ``sim.Settle``), per-device faults and the tracker's measurement volume."""
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
