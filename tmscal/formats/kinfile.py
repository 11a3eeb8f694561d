"""The kinematics file (KIN.yaml): a robot arm's calibrated kinematic parameters, as
``tmscal selfcal identify -o`` writes them, read back into a
:class:`tmscal.calib.selfcal.model.ArmModel` (``tmscal solve --kinematics`` recomputes the
robot poses A from recorded joint values with it; docs/selfcal.md). The same format holds the
arm a calibration identified from the tracker (``tmscal solve --kinematics estimate``, the
``arm.kinematics`` of a calibration file, :mod:`.armfile`; docs/kinematics.md): an arm without
a wrist sensor, read back into an :class:`tmscal.calib.kinematics.Arm`.

The file, YAML (or JSON), units at the edge as docs/conventions.md says (mm, degrees, N, N·m,
kg); the model inside the code is in mm and radians::

    format: tmscal-kinematics
    version: 1
    arm: ur5e                      # the nominal model the parameters were identified from
    convention: standard           # optional: standard (default) or modified DH
    joints:                        # standard DH, T_i = Rz(θ_i + θ0) Tz(d) Tx(a) Rx(α)
      - {theta_offset_deg: 0.0, d_mm: 162.5, a_mm: 0.0, alpha_deg: 90.0,
         min_deg: -360.0, max_deg: 360.0}   # + beta_deg: the Hayati angle (optional: 0)
      - …
    base: [[…], [ …], [ …], [0, 0, 0, 1]]   # world ← base, 4×4 mm (world z up)
    flange: [[…], …]                         # optional: last DH frame ← flange (default I)
    flange_from_sensor: [[…], …]             # the F/T sensor's mounting, 4×4 mm
    tool: {mass_kg: 1.2, cog_mm: [0, 0, 60]} # the tool's centre of gravity, sensor frame
    bias: {force_n: [0, 0, 0], torque_nm: [0, 0, 0]}   # the sensor's offsets
                                   # (these three together, or none: an arm without a sensor)
    identification: {…}            # optional: what was identified, σ, residuals (below)
    session: {path: …, sha256: …}  # optional: the session it was identified on

``convention`` and ``flange`` (docs/kinematics.md: modified DH is Craig's, T_i = Rx(α) Tx(a)
Rz(θ_i + θ0) Tz(d)) are always written; a file without them (older ones) is standard DH with
the flange at the last DH frame.

``identification`` (written by ``selfcal identify``, optional when reading): ``parameters``
(names of the identified parameters, in :meth:`ArmModel.parameter_names` order),
``estimate``, ``std`` and ``nominal`` (one number per name, in the units of
:meth:`ArmModel.vector`: rad, mm, N, N·m, mm), ``covariance`` (their covariance, same
units), ``not_identified`` ({name: reason}), ``iterations``, ``converged``,
``residual_rms`` ({channel: N or N·m}), ``configurations``. An arm identified from the
tracker has ``method: tracker`` and the estimate's report there (:mod:`.armfile`); its
``parameters`` may name the Hayati angles ``beta_i`` too.

Every problem is one :class:`~tmscal.errors.CalibrationError` naming the file and the
dotted key (``"kin.yaml: key 'joints[2].d_mm': …"``); the document is bounded as the rig
config is (32 levels, 100,000 values with YAML aliases expanded, 4 MB).
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..config.values import check_tree
from ..errors import CalibrationError, ConfigError
from ..session import plain
from .textfile import check_matrix as _matrix
from .textfile import load_text as _load_text
from .textfile import read_text_file

__all__ = ["FORMAT", "VERSION", "KinematicsFile", "kinematics_doc", "kinematics_yaml",
           "parse_kinematics", "read_kinematics", "load_arm"]

FORMAT = "tmscal-kinematics"
VERSION = 1
#: the most joints an arm in a kinematics file may have
MAX_JOINTS = 12
#: plausibility bounds of the values (file units)
_LENGTH_MM = 10_000.0
_ANGLE_DEG = 360.0
_LIMIT_DEG = 720.0
_MASS_KG = 1_000.0
_COG_MM = 2_000.0
_FORCE_N = 100_000.0
_TORQUE_NM = 10_000.0
_JOINT_KEYS = ("theta_offset_deg", "d_mm", "a_mm", "alpha_deg", "min_deg", "max_deg")
_TOP_KEYS = ("format", "version", "created", "arm", "convention", "units", "joints", "base",
             "flange", "flange_from_sensor", "tool", "bias", "identification", "session",
             "provenance")


@dataclass
class KinematicsFile:
    """A kinematics file read back: the calibrated ``model`` (an ``ArmModel``, mm and rad),
    the ``path`` it came from, the checked ``doc`` (plain types) and, when the file records
    the identification, the identified parameter names (``identified``), their standard
    deviations (``std``, units of ``ArmModel.vector``) and ``covariance``."""

    model: Any
    path: Path | None
    doc: dict[str, Any] = field(default_factory=dict)
    identified: list[str] = field(default_factory=list)
    std: np.ndarray | None = None
    covariance: np.ndarray | None = None

    @property
    def session(self) -> dict[str, Any]:
        """{"path", "sha256"} of the session the parameters were identified on ({} if
        unknown)."""
        s = self.doc.get("session")
        return dict(s) if isinstance(s, dict) else {}


def _bad(src: str, key: str, msg: str) -> CalibrationError:
    """One line naming the file and the key, whatever the key holds."""
    if not key.isprintable():
        key = key.encode("unicode_escape").decode("ascii")
    return CalibrationError(f"{src}: key '{key}': {msg}")


# --- writing ----------------------------------------------------------------------------------

def _floats(a: Any) -> Any:
    return np.asarray(a, dtype=float).tolist()


def kinematics_doc(model: Any, identification: dict[str, Any] | None = None,
                   session: dict[str, Any] | None = None,
                   provenance: dict[str, Any] | None = None) -> dict[str, Any]:
    """The kinematics document (plain types) of ``model`` (an :class:`~tmscal.calib.
    kinematics.Arm`: DH rows [θ0 rad, d mm, a mm, α rad] in its convention, Hayati angles β
    rad, base = world ← base, flange = last DH frame ← flange 4×4 mm, joint limits rad; an
    ``ArmModel`` adds flange_from_sensor 4×4 mm, tool mass kg and centre of gravity mm in the
    sensor frame, bias [f0 N, τ0 N·m]), with the optional ``identification`` (see the module
    docstring), ``session`` ({path, sha256}) and ``provenance`` entries. ``beta_deg`` is
    written per joint only when some β is not zero, the sensor entries only for an
    ``ArmModel``."""
    dh = np.asarray(model.dh, dtype=float)
    lim = np.asarray(model.joint_limits_rad, dtype=float)
    beta = np.asarray(getattr(model, "beta", None) if getattr(model, "beta", None) is not None
                      else np.zeros(len(dh)), dtype=float)
    joints = [{"theta_offset_deg": float(np.degrees(r[0])), "d_mm": float(r[1]),
               "a_mm": float(r[2]), "alpha_deg": float(np.degrees(r[3])),
               "min_deg": float(np.degrees(lo)), "max_deg": float(np.degrees(hi))}
              for r, (lo, hi) in zip(dh, lim, strict=True)]
    if np.any(beta != 0):
        for j, b in zip(joints, beta, strict=True):
            j["beta_deg"] = float(np.degrees(b))
    doc: dict[str, Any] = {
        "format": FORMAT, "version": VERSION,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "arm": str(model.name),
        "convention": str(getattr(model, "convention", "standard")),
        "units": {"length": "mm", "angle": "deg", "force": "N", "torque": "N·m",
                  "mass": "kg"},
        "joints": joints,
        "base": _floats(model.base),
        "flange": _floats(getattr(model, "flange", np.eye(4))),
    }
    if hasattr(model, "flange_from_sensor"):
        bias = np.asarray(model.bias, dtype=float)
        doc.update({
            "flange_from_sensor": _floats(model.flange_from_sensor),
            "tool": {"mass_kg": float(model.tool_mass_kg),
                     "cog_mm": _floats(model.tool_cog_mm)},
            "bias": {"force_n": bias[:3].tolist(), "torque_nm": bias[3:].tolist()}})
    if identification is not None:
        doc["identification"] = plain(identification)
    if session is not None:
        doc["session"] = plain(session)
    if provenance is not None:
        doc["provenance"] = plain(provenance)
    return doc


def kinematics_yaml(model: Any, **kw: Any) -> str:
    """The YAML text of :func:`kinematics_doc` (``read_kinematics`` reads it back)."""
    return yaml.safe_dump(kinematics_doc(model, **kw), sort_keys=False,
                          default_flow_style=None, width=120, allow_unicode=True)


# --- reading ----------------------------------------------------------------------------------

def _num(v: Any, src: str, key: str, bound: float, lo: float | None = None) -> float:
    """A finite number with |v| ≤ bound (and ≥ lo when given)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise _bad(src, key, f"expected a number, got {_show(v)}")
    try:
        x = float(v)
    except OverflowError:
        raise _bad(src, key, "a number too large for a float") from None
    if not math.isfinite(x):
        raise _bad(src, key, f"{v!r} is not a finite number")
    if abs(x) > bound or (lo is not None and x < lo):
        low = -bound if lo is None else lo
        raise _bad(src, key, f"{x:g} is outside [{low:g}, {bound:g}]")
    return x


def _show(v: Any) -> str:
    r = repr(v) if not isinstance(v, dict | list) else type(v).__name__
    return r if len(r) <= 40 else r[:39] + "…"


def _vec(v: Any, src: str, key: str, n: int, bound: float) -> np.ndarray:
    if not isinstance(v, list) or len(v) != n:
        raise _bad(src, key, f"expected a list of {n} numbers")
    return np.array([_num(x, src, f"{key}[{i}]", bound) for i, x in enumerate(v)])


def _mapping(v: Any, src: str, key: str, keys: tuple[str, ...],
             optional: tuple[str, ...] = ()) -> dict[str, Any]:
    """A mapping with exactly ``keys`` and perhaps ``optional`` ones (a missing or unknown key
    is named)."""
    if not isinstance(v, dict):
        raise _bad(src, key, f"expected a mapping with {', '.join(keys)}")
    for k in v:
        if k not in keys and k not in optional:
            raise _bad(src, f"{key}.{k}", "unknown key; expected one of: "
                       f"{', '.join(keys + optional)}")
    for k in keys:
        if k not in v:
            raise _bad(src, f"{key}.{k}", "missing")
    return v


def _joints(v: Any, src: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """DH rows [θ0 rad, d mm, a mm, α rad], joint limits [min, max] rad and the Hayati angles
    β rad (``beta_deg``, optional: 0)."""
    if not isinstance(v, list) or not 1 <= len(v) <= MAX_JOINTS:
        raise _bad(src, "joints", f"expected a list of 1 to {MAX_JOINTS} joints")
    dh, lim, beta = [], [], []
    for i, j in enumerate(v):
        key = f"joints[{i}]"
        j = _mapping(j, src, key, _JOINT_KEYS, optional=("beta_deg",))
        beta.append(math.radians(_num(j.get("beta_deg", 0.0), src, f"{key}.beta_deg",
                                      _ANGLE_DEG)))
        t0 = _num(j["theta_offset_deg"], src, f"{key}.theta_offset_deg", _ANGLE_DEG)
        d = _num(j["d_mm"], src, f"{key}.d_mm", _LENGTH_MM)
        a = _num(j["a_mm"], src, f"{key}.a_mm", _LENGTH_MM)
        al = _num(j["alpha_deg"], src, f"{key}.alpha_deg", _ANGLE_DEG)
        lo = _num(j["min_deg"], src, f"{key}.min_deg", _LIMIT_DEG)
        hi = _num(j["max_deg"], src, f"{key}.max_deg", _LIMIT_DEG)
        if not lo < hi:
            raise _bad(src, f"{key}.max_deg", f"{hi:g} is not above min_deg {lo:g}")
        dh.append([math.radians(t0), d, a, math.radians(al)])
        lim.append([math.radians(lo), math.radians(hi)])
    return np.array(dh), np.array(lim), np.array(beta)


def _header(doc: Any, src: str) -> str:
    if not isinstance(doc, dict):
        raise CalibrationError(f"{src}: not a tmscal kinematics file (expected a mapping at "
                               f"the top level, got {type(doc).__name__})")
    if doc.get("format") != FORMAT:
        raise _bad(src, "format", f"expected {FORMAT!r}, got {doc.get('format')!r:.60} (a "
                   "file written by tmscal selfcal identify -o)")
    if doc.get("version") != VERSION:
        raise _bad(src, "version", f"this tmscal reads version {VERSION}, got "
                   f"{doc.get('version')!r:.30}")
    for k in doc:
        if k not in _TOP_KEYS:
            raise _bad(src, k, f"unknown key; expected one of: {', '.join(_TOP_KEYS)}")
    arm = doc.get("arm")
    if not isinstance(arm, str) or not arm or len(arm) > 100 or not arm.isprintable():
        raise _bad(src, "arm", "expected the arm's name (a short string)")
    for k in ("units", "session", "provenance"):
        if doc.get(k) is not None and not isinstance(doc[k], dict):
            raise _bad(src, k, "expected a mapping")
    return arm


_SENSOR_KEYS = ("flange_from_sensor", "tool", "bias")


def _fields(doc: Any, src: str) -> dict[str, Any]:
    """The arm's fields (mm, rad) from a document: an ``Arm``'s, and an ``ArmModel``'s sensor
    and tool when the document has them (``flange_from_sensor``, ``tool`` and ``bias``
    together, or none of them)."""
    try:
        check_tree(doc, src)  # the rig config's bounds; its ConfigError becomes ours
    except ConfigError as e:
        raise CalibrationError(str(e)) from None
    name = _header(doc, src)
    dh, lim, beta = _joints(doc.get("joints"), src)
    base = _matrix(doc.get("base"), src, "base", rigid=True)
    convention = doc.get("convention", "standard")
    if convention not in ("standard", "modified"):
        raise _bad(src, "convention", f"expected standard or modified, got {_show(convention)}")
    flange = np.eye(4) if doc.get("flange") is None else \
        _matrix(doc.get("flange"), src, "flange", rigid=True)
    out = {"name": name, "dh": dh, "base": base, "convention": convention, "flange": flange,
           "joint_limits_rad": lim, "beta": beta}
    given = [k for k in _SENSOR_KEYS if doc.get(k) is not None]
    if not given:
        return out
    if len(given) < len(_SENSOR_KEYS):
        missing = next(k for k in _SENSOR_KEYS if k not in given)
        raise _bad(src, missing, f"missing: {', '.join(_SENSOR_KEYS)} (the wrist sensor and "
                   "its tool) go together, or none of them for an arm without one")
    mount = _matrix(doc.get("flange_from_sensor"), src, "flange_from_sensor", rigid=True)
    tool = _mapping(doc.get("tool"), src, "tool", ("mass_kg", "cog_mm"))
    bias = _mapping(doc.get("bias"), src, "bias", ("force_n", "torque_nm"))
    return {**out, "flange_from_sensor": mount,
            "tool_mass_kg": _num(tool["mass_kg"], src, "tool.mass_kg", _MASS_KG, lo=0.0),
            "tool_cog_mm": _vec(tool["cog_mm"], src, "tool.cog_mm", 3, _COG_MM),
            "bias": np.concatenate([_vec(bias["force_n"], src, "bias.force_n", 3, _FORCE_N),
                                    _vec(bias["torque_nm"], src, "bias.torque_nm", 3,
                                         _TORQUE_NM)])}


def _identification(v: Any, src: str, names: list[str]
                    ) -> tuple[list[str], np.ndarray | None, np.ndarray | None]:
    """The identified parameter names (each one of ``names``), their σ and covariance."""
    if v is None:
        return [], None, None
    if not isinstance(v, dict):
        raise _bad(src, "identification", "expected a mapping")
    params = v.get("parameters", [])
    if not isinstance(params, list) or not all(isinstance(p, str) for p in params):
        raise _bad(src, "identification.parameters", "expected a list of parameter names")
    known = set(names)
    for i, p in enumerate(params):
        if p not in known:
            raise _bad(src, f"identification.parameters[{i}]", f"{p!r:.40} is not a "
                       f"parameter of this arm ({len(names)} parameters, e.g. {names[0]!r})")
    if len(set(params)) != len(params):
        raise _bad(src, "identification.parameters", "a parameter is named twice")
    k = len(params)
    std = cov = None
    for key in ("estimate", "std", "nominal"):
        if v.get(key) is not None:
            a = _vec(v[key], src, f"identification.{key}", k, 1e12)
            if key == "std":
                if (a < 0).any():
                    raise _bad(src, "identification.std", "a standard deviation is negative")
                std = a
    if v.get("covariance") is not None:
        c = v["covariance"]
        if not isinstance(c, list) or len(c) != k:
            raise _bad(src, "identification.covariance", f"expected a {k}×{k} matrix")
        cov = np.array([_vec(r, src, f"identification.covariance[{i}]", k, 1e24)
                        for i, r in enumerate(c)]).reshape(k, k)
        if not np.allclose(cov, cov.T, rtol=1e-6, atol=1e-30):
            raise _bad(src, "identification.covariance", "not symmetric")
    return list(params), std, cov


def _parameter_names(model: Any) -> list[str]:
    """The names an identification may give: an ``ArmModel``'s parameter vector, or an arm's
    DH parameters (θ0, d, a, α per joint), and β of every joint (the tracker-based
    estimate's Hayati angles)."""
    n = model.n_joints
    per = (list(model.parameter_names()) if hasattr(model, "parameter_names") else
           [f"{k}_{i}" for i in range(1, n + 1) for k in ("theta0", "d", "a", "alpha")])
    return per + [f"beta_{i}" for i in range(1, n + 1)]


def parse_kinematics(doc: Any, src: str = "<kinematics>") -> KinematicsFile:
    """A :class:`KinematicsFile` from a parsed document (a dict as the file holds it); its
    ``model`` is an ``ArmModel`` (mm, rad) when the document has the wrist sensor and its
    tool, else an :class:`~tmscal.calib.kinematics.Arm`. Raises CalibrationError naming
    ``src`` and the key."""
    from ..calib.kinematics.model import Arm
    from ..calib.selfcal.model import ArmModel

    f = _fields(doc, src)
    try:
        model = ArmModel(**f) if "bias" in f else Arm(**f)
        names = _parameter_names(model)
    except (TypeError, ValueError) as e:
        raise CalibrationError(f"{src}: not a valid arm model ({e})") from None
    params, std, cov = _identification(doc.get("identification"), src, names)
    return KinematicsFile(model=model, path=None, doc=doc, identified=params, std=std,
                          covariance=cov)


def read_kinematics(path: str | Path) -> KinematicsFile:
    """Read a kinematics file (YAML of ``tmscal selfcal identify -o``, or the same as JSON):
    the calibrated ``ArmModel`` (mm, rad) and what the file records of its identification.
    Raises CalibrationError naming the file (and the key)."""
    p = Path(path)
    src = str(p)
    kf = parse_kinematics(_load_text(read_text_file(p, "kinematics file", "kinematics"), src), src)
    kf.path = p
    return kf


def load_arm(path: str | Path) -> Any:
    """The calibrated ``ArmModel`` (mm, rad) stored in a kinematics file."""
    return read_kinematics(path).model
