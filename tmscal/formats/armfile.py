"""The identified arm of a calibration file (``Calibration.arm``, an
:class:`~tmscal.calib.kinematics.calibrated.ArmCalibration`; docs/kinematics.md, "Using it"):
the ``arm`` section that ``tmscal solve --kinematics … -o`` writes and
:func:`tmscal.exports.load_calibration` reads back. The arm itself is stored in the kinematics
format of :mod:`.kinfile`, the one ``tmscal selfcal identify -o`` writes::

    arm:
      nominal: ur5e              # the controller's model, a name of tmscal's arm registry
      nominal_arm: {…}           # only for an arm of a URDF or an arm file: that arm, in
                                 # the kinematics format (so a check needs no file)
      source: estimated          # estimated (tmscal solve --kinematics estimate) or the
                                 # kinematics file the robot poses were recomputed with
      controller_frame: [[…]]    # 4×4 mm: the controller's frame ← the arm's DH base
      seeds_deg: [[…], …]        # joint configurations (deg) of the calibration's poses,
                                 # the seeds of the inverse kinematics
      kinematics: {format: tmscal-kinematics, version: 1, arm: ur5e, joints: […], …,
                   identification: {…}}

For an estimated arm, ``kinematics.identification`` is the estimate's report: ``method:
tracker``, ``level`` and ``reason`` (the held-out choice), ``tolerances`` {length_mm,
angle_deg} (the prior), ``parameters`` (the deviations' names: theta0_i, d_i, a_i, alpha_i,
beta_i), ``estimate`` and ``nominal`` (their identified and nominal values, rad and mm, as a
kinematics file's identification gives them) and ``std`` (posterior σ), ``identified``,
``weak`` and ``unidentified`` (the combinations: ``text``, ``terms``, ``sigma_data``,
``estimate``, ``sd`` in tolerance units, ``reason``), ``cv`` (the held-out e_t per level, mm),
``variance_factor``, ``iterations``. For an arm from a kinematics file it is that file's
identification, as it was.

Every problem is one CalibrationError naming the file and the dotted key.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..calib.kinematics.calibrated import MAX_SEEDS, ArmCalibration
from ..errors import CalibrationError
from ..session import plain
from .kinfile import kinematics_doc, parse_kinematics
from .textfile import bad, check_matrix

__all__ = ["arm_section", "parse_arm_section"]

_KEYS = ("nominal", "nominal_arm", "source", "controller_frame", "seeds_deg", "kinematics")
#: the report entries of an estimated arm, beside parameters/estimate/nominal/std
_REPORT = ("level", "reason", "tolerances", "identified", "weak", "unidentified", "cv",
           "variance_factor", "iterations")
_MAX_SEEDS = 4 * MAX_SEEDS


def arm_section(ac: ArmCalibration) -> dict[str, Any]:
    """The ``arm`` section (plain types; module docstring) of an identified arm."""
    rep = ac.report or {}
    if "deviations" in rep:
        names = list(rep["deviations"])
        ident: dict[str, Any] | None = {
            "method": "tracker",
            **{k: rep[k] for k in _REPORT if k in rep},
            "parameters": names,
            "estimate": [ac.arm.deviation(n) for n in names],
            "nominal": [ac.nominal.deviation(n) for n in names],
            "std": [float(rep.get("sd", {}).get(n, 0.0)) for n in names]}
        source = "estimated"
    else:
        ident = rep.get("identification")
        source = str(rep.get("source", "given"))
    seeds = [] if ac.seeds is None else np.degrees(np.asarray(ac.seeds, dtype=float)).tolist()
    out = {}
    if not _registered(ac.nominal):  # an arm of a URDF or an arm file: kept whole
        out["nominal_arm"] = kinematics_doc(ac.nominal)
    return plain({"nominal": ac.nominal.name, **out, "source": source,
                  "controller_frame": np.asarray(ac.controller_frame, dtype=float).tolist(),
                  "seeds_deg": seeds,
                  "kinematics": kinematics_doc(ac.arm, identification=ident)})


def _registered(arm: Any) -> bool:
    """The arm is the registry's arm of its name, as it is there."""
    from ..calib.kinematics.arms import ARMS

    spec = ARMS.get(arm.name)
    return spec is not None and _same(spec.arm.to_dict(), arm.to_dict())


def _same(a: Any, b: Any) -> bool:
    return bool(np.array_equal(np.asarray(a["dh"]), np.asarray(b["dh"]))) and all(
        a.get(k) == b.get(k) for k in ("convention", "base", "flange", "joint_limits_rad",
                                       "beta", "joint_types", "joint_map", "root"))


def _seeds(v: Any, src: str, n: int) -> np.ndarray | None:
    key = "arm.seeds_deg"
    if v is None or v == []:
        return None
    if not isinstance(v, list) or len(v) > _MAX_SEEDS:
        raise bad(src, key, f"expected a list of at most {_MAX_SEEDS} joint configurations")
    rows = []
    for i, r in enumerate(v):
        if not isinstance(r, list) or len(r) != n:
            raise bad(src, f"{key}[{i}]", f"expected {n} joint angles (deg)")
        for j, x in enumerate(r):
            if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x) \
                    or abs(x) > 720.0:
                raise bad(src, f"{key}[{i}][{j}]", "expected a finite angle within ±720°")
        rows.append(r)
    return np.radians(np.array(rows, dtype=float))


def _combos(v: Any, src: str, key: str) -> list[dict[str, Any]]:
    if v is None:
        return []
    if not isinstance(v, list) or not all(isinstance(c, dict) and isinstance(c.get("text"), str)
                                          for c in v):
        raise bad(src, key, "expected a list of combinations, each a mapping with its 'text'")
    return [dict(c) for c in v]


def _numbers(v: Any, keys: tuple[str, ...], src: str, key: str) -> None:
    """``v`` is None or a mapping whose ``keys`` are finite numbers ≥ 0."""
    if v is None:
        return
    if not isinstance(v, dict):
        raise bad(src, key, f"expected a mapping with {', '.join(keys)}")
    for k in keys:
        x = v.get(k)
        if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x) \
                or x < 0:
            raise bad(src, f"{key}.{k}", "expected a finite number ≥ 0")


def _report(ident: Any, src: str) -> dict[str, Any]:
    """The ArmCalibration.report of an estimated arm's identification (already checked by
    the kinematics reader: names, and estimate/nominal/std of one number per name)."""
    key = "arm.kinematics.identification"
    names = list(ident.get("parameters") or [])
    est = np.asarray(ident.get("estimate") or [0.0] * len(names), dtype=float)
    nom = np.asarray(ident.get("nominal") or [0.0] * len(names), dtype=float)
    sd = np.asarray(ident.get("std") or [0.0] * len(names), dtype=float)
    rep: dict[str, Any] = {k: ident[k] for k in _REPORT if k in ident}
    for k in ("identified", "weak", "unidentified"):
        rep[k] = _combos(ident.get(k), src, f"{key}.{k}")
    if not isinstance(rep.get("level"), str):
        raise bad(src, f"{key}.level", "expected the level (none, offsets or full)")
    if not isinstance(rep.get("reason", ""), str):
        raise bad(src, f"{key}.reason", "expected a text")
    _numbers(rep.get("tolerances"), ("length_mm", "angle_deg"), src, f"{key}.tolerances")
    cv = rep.get("cv")
    if cv is not None:
        if not isinstance(cv, dict):
            raise bad(src, f"{key}.cv", "expected a mapping of level to held-out errors")
        for lv, c in cv.items():
            if c is not None:
                _numbers(c, ("e_t_mm", "se_mm", "folds"), src, f"{key}.cv.{lv}")
    rep["deviations"] = {n: float(e - o) for n, e, o in zip(names, est, nom, strict=True)}
    rep["sd"] = {n: float(s) for n, s in zip(names, sd, strict=True)}
    return rep


def parse_arm_section(v: Any, src: str) -> ArmCalibration:
    """The :class:`ArmCalibration` of a calibration file's ``arm`` section (module docstring).
    Raises CalibrationError naming ``src`` and the key."""
    from ..calib.kinematics.arms import arm_by_name

    if not isinstance(v, dict):
        raise bad(src, "arm", "expected a mapping (nominal, source, controller_frame, "
                  "seeds_deg, kinematics)")
    for k in v:
        if k not in _KEYS:
            raise bad(src, f"arm.{k}", f"unknown key; expected one of: {', '.join(_KEYS)}")
    for k in ("nominal", "controller_frame", "kinematics"):
        if v.get(k) is None:
            raise bad(src, f"arm.{k}", "missing")
    if v.get("nominal_arm") is not None:   # an arm of a URDF or an arm file, kept whole
        nominal = parse_kinematics(v["nominal_arm"], f"{src}, arm.nominal_arm").model
        if nominal.name != v["nominal"]:
            raise bad(src, "arm.nominal", f"{str(v['nominal'])[:60]!r} is not the name of "
                      f"arm.nominal_arm ({nominal.name!r})")
    else:
        try:
            nominal = arm_by_name(v["nominal"], f"{src}: key 'arm.nominal'")
        except Exception as e:  # the registry's ConfigError, typed as the file's
            raise CalibrationError(str(e)) from None
    kf = parse_kinematics(v["kinematics"], f"{src}, arm.kinematics")
    arm = kf.model
    if (arm.name, arm.n_joints, arm.convention) != \
            (nominal.name, nominal.n_joints, nominal.convention):
        raise bad(src, "arm.kinematics", f"the {arm.name} arm ({arm.n_joints} joints, "
                  f"{arm.convention} DH) is not a {nominal.name} ({nominal.n_joints}, "
                  f"{nominal.convention}), the nominal arm named in arm.nominal")
    M = check_matrix(v["controller_frame"], src, "arm.controller_frame", rigid=True)
    seeds = _seeds(v.get("seeds_deg"), src, nominal.n_joints)
    ident = v["kinematics"].get("identification")
    source = v.get("source", "estimated")
    if not isinstance(source, str):
        raise bad(src, "arm.source", "expected 'estimated' or the kinematics file's name")
    if isinstance(ident, dict) and ident.get("method") == "tracker":
        report = _report(ident, src)
    else:
        report = {"source": source, "identification": ident}
    return ArmCalibration(nominal=nominal, arm=arm, controller_frame=M, seeds=seeds,
                          report=report)
