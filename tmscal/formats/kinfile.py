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

The same format is the tmscal **arm file** (docs/kinematics.md, "Arm files"), which may add,
per joint, ``type`` (revolute or prismatic: q in mm adds to d, its range ``min_mm``/``max_mm``),
``sign`` (1 or −1), ``coupling`` ([{joint, factor}]: the row also moves with other joints,
FANUC's J2/J3), ``mimic`` ([{joint, factor}]: a passive row with no joint of its own, no range)
and ``name``; at the top ``root`` (robot base ← DH frame 0), ``description`` (vendor, model,
source, approximate, controller_model, generation, reach_mm, notes) and ``mock`` (serial,
mount, home_deg); ``base`` is optional (identity) and every transform may be a 4×4 matrix or
``{xyz_mm, rpy_deg}``.

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
             "root", "flange", "flange_from_sensor", "tool", "bias", "identification", "session",
             "provenance", "description", "mock")


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


def _joint_docs(model: Any, dh: np.ndarray, lim: np.ndarray) -> list[dict[str, Any]]:
    """The ``joints`` entries of an arm: its DH rows, and (when not plain) each row's type,
    sign, couplings or mimic entries from the joint map (module docstring)."""
    types = tuple(getattr(model, "types", ("revolute",) * len(dh)))
    M = getattr(model, "joint_map", None)
    M = np.eye(len(dh)) if M is None else np.asarray(M, dtype=float)
    own: list[int] = []             # each joint's own row: increasing, its factor ±1
    for j in range(M.shape[1]):
        rows = [r for r in range(len(dh)) if r > (own[-1] if own else -1)
                and abs(M[r, j]) == 1.0]
        if not rows:
            raise ValueError(f"joint {j + 1} of the joint map has no row of its own (a row "
                             "after the previous joint's with factor 1 or -1)")
        own.append(rows[0])
    out = []
    for i, r in enumerate(dh):
        e: dict[str, Any] = {"theta_offset_deg": float(np.degrees(r[0])), "d_mm": float(r[1]),
                             "a_mm": float(r[2]), "alpha_deg": float(np.degrees(r[3]))}
        if types[i] != "revolute":
            e = {"type": types[i], **e}
        links = [{"joint": int(j) + 1, "factor": float(M[i, j])}
                 for j in np.flatnonzero(M[i]) if i not in own or own.index(i) != j]
        if i in own:
            j = own.index(i)
            lo, hi = lim[j]
            if types[i] == "prismatic":
                e.update({"min_mm": float(lo), "max_mm": float(hi)})
            else:
                e.update({"min_deg": float(np.degrees(lo)), "max_deg": float(np.degrees(hi))})
            if M[i, j] != 1.0:
                if abs(M[i, j]) != 1.0:
                    raise ValueError(f"row {i + 1}: a joint's own factor must be 1 or -1")
                e["sign"] = int(M[i, j])
            if links:
                e["coupling"] = links
        else:
            e["mimic"] = links
        out.append(e)
    return out


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
    joints = _joint_docs(model, dh, lim)
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
    if getattr(model, "root", None) is not None:
        doc["root"] = _floats(model.root)
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
        raise _bad(src, key, f"expected a mapping with {', '.join(keys or optional)}")
    for k in v:
        if not isinstance(k, str):
            raise _bad(src, f"{key}.{_show(k)}", "every key must be a string")
        if k not in keys and k not in optional:
            raise _bad(src, f"{key}.{k}", "unknown key; expected one of: "
                       f"{', '.join(keys + optional)}")
    for k in keys:
        if k not in v:
            raise _bad(src, f"{key}.{k}", "missing")
    return v


_TYPES = ("revolute", "prismatic")
_JOINT_OPTIONAL = ("beta_deg", "type", "sign", "coupling", "mimic", "name", "min_mm", "max_mm")


def _links(v: Any, src: str, key: str, n_max: int) -> list[tuple[int, float]]:
    """A list of {joint: j (1-based joint number), factor: c} (a coupling or a mimic)."""
    if not isinstance(v, list) or not v:
        raise _bad(src, key, "expected a list of {joint: J, factor: C} (J a joint number "
                   "counted from 1, C a finite number)")
    out = []
    for k, e in enumerate(v):
        e = _mapping(e, src, f"{key}[{k}]", ("joint", "factor"))
        j = e["joint"]
        if isinstance(j, bool) or not isinstance(j, int) or not 1 <= j <= n_max:
            raise _bad(src, f"{key}[{k}].joint", f"expected a joint number in 1…{n_max}, got "
                       f"{_show(j)}")
        out.append((j, _num(e["factor"], src, f"{key}[{k}].factor", 1e3)))
    return out


def _joints(v: Any, src: str) -> dict[str, Any]:
    """The arm's rows and joints: ``dh`` rows [θ0 rad, d mm, a mm, α rad], ``joint_limits_rad``
    [min, max] per joint (rad; mm for a prismatic one), ``beta`` the Hayati angles rad
    (``beta_deg``, optional: 0), ``joint_types`` and ``joint_map`` (``type``, ``sign``,
    ``coupling``, ``mimic``: docs/kinematics.md, "Arm files")."""
    if not isinstance(v, list) or not 1 <= len(v) <= MAX_JOINTS:
        raise _bad(src, "joints", f"expected a list of 1 to {MAX_JOINTS} joints")
    dh, lim, beta, types = [], [], [], []
    own: list[int | None] = []          # the joint number (0-based) of each row, None: mimic
    links: list[list[tuple[int, float]]] = []
    signs: list[float] = []
    for i, j in enumerate(v):
        key = f"joints[{i}]"
        if not isinstance(j, dict):
            raise _bad(src, key, f"expected a mapping with {', '.join(_JOINT_KEYS)}")
        kind = j.get("type", "revolute")
        if kind not in _TYPES:
            raise _bad(src, f"{key}.type", f"expected revolute or prismatic, got {_show(kind)}")
        mimic = j.get("mimic") is not None
        need = ["theta_offset_deg", "d_mm", "a_mm", "alpha_deg"]
        lim_keys = ("min_mm", "max_mm") if kind == "prismatic" else ("min_deg", "max_deg")
        if not mimic:
            need += list(lim_keys)
        allowed = tuple(need) + _JOINT_OPTIONAL + ("min_deg", "max_deg")
        for k in j:
            if k not in allowed or (k in ("min_deg", "max_deg", "min_mm", "max_mm")
                                    and (mimic or k not in lim_keys)):
                why = ("a passive (mimic) joint has no limits of its own" if mimic and
                       k in ("min_deg", "max_deg", "min_mm", "max_mm") else
                       f"a {kind} joint's limits are {' and '.join(lim_keys)}"
                       if k in ("min_deg", "max_deg", "min_mm", "max_mm") else
                       f"unknown key; expected one of: {', '.join(tuple(need) + _JOINT_OPTIONAL)}")
                raise _bad(src, f"{key}.{k}", why)
        for k in need:
            if k not in j:
                raise _bad(src, f"{key}.{k}", "missing")
        if j.get("name") is not None and (not isinstance(j["name"], str) or len(j["name"]) > 100):
            raise _bad(src, f"{key}.name", "expected the joint's name (a short string)")
        beta.append(math.radians(_num(j.get("beta_deg", 0.0), src, f"{key}.beta_deg",
                                      _ANGLE_DEG)))
        t0 = _num(j["theta_offset_deg"], src, f"{key}.theta_offset_deg", _ANGLE_DEG)
        d = _num(j["d_mm"], src, f"{key}.d_mm", _LENGTH_MM)
        a = _num(j["a_mm"], src, f"{key}.a_mm", _LENGTH_MM)
        al = _num(j["alpha_deg"], src, f"{key}.alpha_deg", _ANGLE_DEG)
        dh.append([math.radians(t0), d, a, math.radians(al)])
        types.append(kind)
        if mimic:
            if "sign" in j or "coupling" in j:
                raise _bad(src, f"{key}.{'sign' if 'sign' in j else 'coupling'}",
                           "a passive (mimic) joint follows its mimic entries only")
            own.append(None)
            links.append(_links(j["mimic"], src, f"{key}.mimic", MAX_JOINTS))
            signs.append(0.0)
            continue
        bound = _LENGTH_MM if kind == "prismatic" else _LIMIT_DEG
        lo = _num(j[lim_keys[0]], src, f"{key}.{lim_keys[0]}", bound)
        hi = _num(j[lim_keys[1]], src, f"{key}.{lim_keys[1]}", bound)
        if not lo < hi:
            raise _bad(src, f"{key}.{lim_keys[1]}", f"{hi:g} is not above {lim_keys[0]} {lo:g}")
        lim.append([lo, hi] if kind == "prismatic" else [math.radians(lo), math.radians(hi)])
        sign = j.get("sign", 1)
        if sign not in (1, -1) or isinstance(sign, bool):
            raise _bad(src, f"{key}.sign", f"expected 1 or -1, got {_show(sign)}")
        own.append(sum(o is not None for o in own))
        signs.append(float(sign))
        links.append([] if j.get("coupling") is None else
                     _links(j["coupling"], src, f"{key}.coupling", MAX_JOINTS))
    n = sum(o is not None for o in own)
    if n == 0:
        raise _bad(src, "joints", "every joint is passive (mimic): no joint moves the arm")
    kinds = [types[i] for i, o in enumerate(own) if o is not None]
    M = np.zeros((len(dh), n))
    for i, o in enumerate(own):
        if o is not None:
            M[i, o] = signs[i]
        sub = "mimic" if o is None else "coupling"
        for k, (jn, c) in enumerate(links[i]):
            if jn > n:
                raise _bad(src, f"joints[{i}].{sub}[{k}].joint", f"joint {jn}: the arm has {n} "
                           "joints (passive rows not counted)")
            if jn - 1 == o:
                raise _bad(src, f"joints[{i}].{sub}[{k}].joint", "a joint coupled to itself "
                           "(give its sign instead)")
            if kinds[jn - 1] != types[i]:
                raise _bad(src, f"joints[{i}].{sub}[{k}].joint", f"couples this {types[i]} "
                           f"joint to joint {jn}, a {kinds[jn - 1]} one")
            M[i, jn - 1] += c
    plain_map = M.shape[0] == M.shape[1] and np.array_equal(M, np.eye(n))
    return {"dh": np.array(dh), "joint_limits_rad": np.array(lim), "beta": np.array(beta),
            "joint_types": None if all(t == "revolute" for t in types) else tuple(types),
            "joint_map": None if plain_map else M}


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


def _pose(v: Any, src: str, key: str) -> np.ndarray:
    """A rigid 4×4 (mm): a matrix, or {xyz_mm: [x, y, z], rpy_deg: [roll, pitch, yaw]}
    (Trans(xyz) · Rz(yaw) Ry(pitch) Rx(roll), as a URDF origin)."""
    if isinstance(v, dict):
        from ..calib.kinematics.model import pose_from_rpy

        v = _mapping(v, src, key, (), optional=("xyz_mm", "rpy_deg"))
        xyz = _vec(v.get("xyz_mm", [0, 0, 0]), src, f"{key}.xyz_mm", 3, _LENGTH_MM)
        rpy = _vec(v.get("rpy_deg", [0, 0, 0]), src, f"{key}.rpy_deg", 3, _ANGLE_DEG)
        return pose_from_rpy(np.radians(rpy), xyz)
    return _matrix(v, src, key, rigid=True)


#: what an arm file may say of the arm beside its kinematics (``description``) and where the
#: mock rig places it (``mock``); docs/kinematics.md, "Arm files"
_ABOUT_KEYS = ("vendor", "model", "source", "approximate", "controller_model", "generation",
               "reach_mm", "notes")
_MOCK_KEYS = ("serial", "mount", "home_deg")


def _about(doc: dict[str, Any], src: str) -> None:
    """``description`` and ``mock``: checked, kept in the document."""
    d = doc.get("description")
    if d is not None:
        d = _mapping(d, src, "description", (), optional=_ABOUT_KEYS)
        for k in ("vendor", "model", "source", "controller_model", "generation", "notes"):
            if d.get(k) is not None and (not isinstance(d[k], str) or len(d[k]) > 2000):
                raise _bad(src, f"description.{k}", "expected a text")
        if d.get("approximate") is not None and not isinstance(d["approximate"], bool):
            raise _bad(src, "description.approximate", "expected true or false")
        if d.get("reach_mm") is not None:
            _num(d["reach_mm"], src, "description.reach_mm", _LENGTH_MM, lo=0.0)
    m = doc.get("mock")
    if m is not None:
        m = _mapping(m, src, "mock", (), optional=_MOCK_KEYS)
        if m.get("mount") is not None:
            _pose(m["mount"], src, "mock.mount")
        if m.get("serial") is not None and not isinstance(m["serial"], str):
            raise _bad(src, "mock.serial", "expected a text")


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
    rows = _joints(doc.get("joints"), src)
    base = np.eye(4) if doc.get("base") is None else _pose(doc.get("base"), src, "base")
    convention = doc.get("convention", "standard")
    if convention not in ("standard", "modified"):
        raise _bad(src, "convention", f"expected standard or modified, got {_show(convention)}")
    flange = np.eye(4) if doc.get("flange") is None else _pose(doc.get("flange"), src, "flange")
    out = {"name": name, "base": base, "convention": convention, "flange": flange, **rows}
    if doc.get("root") is not None:
        out["root"] = _pose(doc.get("root"), src, "root")
    _about(doc, src)
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
    DH parameters (θ0, d, a, α per DH row), and β of every row (the tracker-based
    estimate's Hayati angles)."""
    n = getattr(model, "n_rows", model.n_joints)
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
