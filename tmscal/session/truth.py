"""The ground truth a simulated session's header may carry (docs/session-format.md, "truth"):
X = flange_from_marker, Z = base_from_tracker and optionally Y = flange_from_probe (4×4 mm),
and optionally the rig's ``arm`` (its name, error protocol, nominal and true geometry, mount).
Checked alike by the writer and the reader; no file I/O."""

from __future__ import annotations

from typing import Any

import numpy as np

from .checks import MAX_JOINT_RAD, BadLine, parse_matrix, parse_numbers

_TRUTH_KEYS = ("X", "Y", "Z")
_TRUTH_ARM_KEYS = ("name", "errors", "nominal", "true", "mount")
_ARM_KEYS = ("name", "convention", "dh", "base", "flange", "joint_limits_rad", "beta")
#: an arm in a header has at most this many joints; a length beyond 10 m in its table is
#: corruption (angles: beyond ±1000 rad, ``MAX_JOINT_RAD``)
_MAX_ARM_JOINTS = 32
_MAX_ARM_LENGTH_MM = 1e4
#: the longest name or error protocol the truth's arm may give
_MAX_NAME = 100


def validate_truth(t: Any) -> dict[str, np.ndarray]:
    """The truth's X, Z[, Y] (4×4 mm); its ``arm``, when present, is checked too
    (:func:`validate_truth_arm`). BadLine naming the key otherwise."""
    if not isinstance(t, dict):
        raise BadLine("field 'truth' must be an object")
    extra = [k for k in t if k not in _TRUTH_KEYS and k != "arm"]
    if extra:
        raise BadLine(f"field 'truth': unknown key {str(extra[0])[:40]!r} (expected X, Y, Z, "
                   "arm)")
    out = {}
    for k in _TRUTH_KEYS:
        M = parse_matrix(t.get(k), f"truth.{k}")
        if M is None and k != "Y":
            raise BadLine(f"field 'truth.{k}' is missing")
        if M is not None:
            out[k] = M
    if "arm" in t:
        validate_truth_arm(t["arm"])
    return out


def validate_truth_arm(a: Any) -> dict[str, Any]:
    """The truth's ``arm``: {"name", "errors": non-empty strings, "nominal", "true": arms as
    ``Arm.to_dict`` writes them (mm, rad; alike in joints and convention), "mount": 4×4 mm
    rig frame ← robot base}, returned as {"name", "errors", "nominal": Arm, "true": Arm,
    "mount": ndarray}; BadLine naming the key otherwise."""
    if not isinstance(a, dict):
        raise BadLine("field 'truth.arm' must be an object")
    for k in a:
        if k not in _TRUTH_ARM_KEYS:
            raise BadLine(f"field 'truth.arm': unknown key {str(k)[:40]!r} (expected "
                       f"{', '.join(_TRUTH_ARM_KEYS)})")
    for k in _TRUTH_ARM_KEYS:
        if k not in a:
            raise BadLine(f"field 'truth.arm.{k}' is missing")
    for k in ("name", "errors"):
        if not (isinstance(a[k], str) and 0 < len(a[k]) <= _MAX_NAME):
            raise BadLine(f"field 'truth.arm.{k}' must be a non-empty string (at most "
                       f"{_MAX_NAME} characters)")
    mount = parse_matrix(a["mount"], "truth.arm.mount")
    if mount is None:
        raise BadLine("field 'truth.arm.mount' must be a 4×4 matrix, not null")
    nominal = _check_arm(a["nominal"], "truth.arm.nominal")
    true = _check_arm(a["true"], "truth.arm.true")
    if (true.n_joints, true.convention) != (nominal.n_joints, nominal.convention):
        raise BadLine(f"field 'truth.arm.true': {true.n_joints} joints, {true.convention} DH; "
                   f"the nominal arm has {nominal.n_joints}, {nominal.convention}")
    return {"name": a["name"], "errors": a["errors"], "nominal": nominal, "true": true,
            "mount": mount}


def _rows(value: Any, name: str, n: int | None, width: int, what: str, bound: float
          ) -> list[list[float]]:
    """``n`` rows (None: 1 to ``_MAX_ARM_JOINTS``) of ``width`` finite numbers each, every
    one of magnitude below ``bound``."""
    count = f"1 to {_MAX_ARM_JOINTS}" if n is None else f"{n}"
    if not (type(value) is list and (1 <= len(value) <= _MAX_ARM_JOINTS if n is None
                                     else len(value) == n)):
        raise BadLine(f"field '{name}': expected a list of {count} rows ({what})")
    out = [parse_numbers(r, name, what, width, bound, exact=True) for r in value]
    if any(r is None for r in out):
        raise BadLine(f"field '{name}': a row is null, expected {width} numbers ({what})")
    return out  # type: ignore[return-value]


def _check_arm(d: Any, where: str) -> Any:
    """An arm as ``tmscal.calib.kinematics.Arm.to_dict`` writes it: name, convention
    (optional: standard), dh (n rows [θ0 rad, d mm, a mm, α rad]), base and flange (4×4 mm;
    flange optional: identity), joint_limits_rad (n rows [low, high] rad), beta (optional: n
    Hayati angles, rad). The :class:`~tmscal.calib.kinematics.Arm`, or BadLine naming the key."""
    from ..calib.kinematics.model import CONVENTIONS, Arm

    if not isinstance(d, dict):
        raise BadLine(f"field '{where}' must be an object")
    for k in d:
        if k not in _ARM_KEYS:
            raise BadLine(f"field '{where}': unknown key {str(k)[:40]!r} (expected "
                       f"{', '.join(_ARM_KEYS)})")
    for k in ("name", "dh", "base", "joint_limits_rad"):
        if k not in d:
            raise BadLine(f"field '{where}.{k}' is missing")
    if not (isinstance(d["name"], str) and len(d["name"]) <= _MAX_NAME):
        raise BadLine(f"field '{where}.name' must be a string (at most {_MAX_NAME} characters)")
    convention = d.get("convention", "standard")
    if convention not in CONVENTIONS:
        raise BadLine(f"field '{where}.convention' must be one of {', '.join(CONVENTIONS)}")
    dh = _rows(d["dh"], f"{where}.dh", None, 4, "[θ0 rad, d mm, a mm, α rad]",
               _MAX_ARM_LENGTH_MM)
    lim = _rows(d["joint_limits_rad"], f"{where}.joint_limits_rad", len(dh), 2,
                "[low, high] rad", MAX_JOINT_RAD)
    if any(lo > hi for lo, hi in lim):
        raise BadLine(f"field '{where}.joint_limits_rad': a low limit above its high one")
    beta = parse_numbers(d.get("beta"), f"{where}.beta", "Hayati angles (rad)", len(dh),
                    MAX_JOINT_RAD, exact=True)
    base = parse_matrix(d["base"], f"{where}.base")
    if base is None:
        raise BadLine(f"field '{where}.base' must be a 4×4 matrix, not null")
    flange = parse_matrix(d.get("flange"), f"{where}.flange")
    try:
        return Arm(name=d["name"], dh=np.asarray(dh, dtype=float), base=base,
                   joint_limits_rad=np.asarray(lim, dtype=float), convention=convention,
                   flange=np.eye(4) if flange is None else flange,
                   beta=None if beta is None else np.asarray(beta, dtype=float))
    except ValueError as e:
        raise BadLine(f"field '{where}': {e}") from None
