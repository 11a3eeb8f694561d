"""Session records: the line formats of a session file (header and pose lines), their
validation (the same for the writer and the reader), ``PoseRecord`` and ``make_header``.
Matrices are 4×4 mm: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe.
No file I/O here; ``tmscal.session.files`` reads and writes.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import SessionError
from .jsonable import json_default

log = logging.getLogger(__name__)

FORMAT = "tmscal-session"
VERSION = 1
_MATRIX_KEYS = ("A", "B", "C", "commanded")
_TRUTH_KEYS = ("X", "Y", "Z")
#: sanity bounds: a translation beyond 10 km, an index or count beyond 10⁹ is corruption
_MAX_TRANS_MM = 1e7
_MAX_COUNT = 10 ** 9
_RIGID_TOL = 1e-4
#: a JSON \\u escape of a UTF-16 surrogate (the only way a line can carry a lone surrogate)
_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89abcdefABCDEF]")


class BadLine(Exception):
    """A line fails validation; the message is the reason without file and line."""


# --- validation (shared by the reader and the writer) --------------------------------------

def _reject_constant(name: str) -> Any:
    raise ValueError(f"non-finite number {name} (JSON has no NaN or infinity)")


def _finite_float(text: str) -> float:
    x = float(text)
    if not math.isfinite(x):
        raise ValueError(f"number {text[:40]} is out of range (not a finite float64)")
    return x


def parse_json(text: str, finite: bool = True) -> Any:
    """json.loads that refuses NaN and Infinity literals and, with ``finite``, numbers that
    overflow float64 anywhere (pose lines skip that slower check: every number the reader
    keeps from them is checked for finiteness field by field)."""
    try:
        obj = json.loads(text, parse_constant=_reject_constant,
                         parse_float=_finite_float if finite else None)
    except RecursionError:
        raise BadLine("not valid JSON (nested too deeply)") from None
    except json.JSONDecodeError as e:
        raise BadLine(f"not valid JSON ({e.msg} at column {e.colno})") from None
    except ValueError as e:  # the int digit limit, our parse hooks
        raise BadLine(f"not valid JSON ({str(e)[:120]})") from None
    if _SURROGATE_ESCAPE.search(text):
        try:
            json.dumps(obj, ensure_ascii=False).encode("utf-8")
        except UnicodeEncodeError:
            raise BadLine("a string holds an unpaired UTF-16 surrogate (not valid Unicode)") \
                from None
    return obj


def _dumps(obj: Any) -> str:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False, default=json_default)


_NUMBER_TYPES = frozenset((int, float))
_EYE3 = np.eye(3)


def _is_number(x: Any) -> bool:
    return type(x) in _NUMBER_TYPES  # not bool, not str


def _matrix(value: Any, name: str) -> np.ndarray | None:
    """A 4×4 rigid transform (mm) from a JSON value, or None for null."""
    if value is None:
        return None
    if not (type(value) is list and len(value) == 4
            and all(type(r) is list and len(r) == 4 for r in value)):
        raise BadLine(f"field '{name}': expected a 4×4 matrix (4 rows of 4 numbers)")
    if not all(_NUMBER_TYPES.issuperset(map(type, r)) for r in value):
        raise BadLine(f"field '{name}': entries must be numbers")
    try:
        M = np.array(value, dtype=np.float64)
    except (OverflowError, ValueError, TypeError):
        raise BadLine(f"field '{name}': a number is out of range") from None
    if not np.isfinite(M).all():
        raise BadLine(f"field '{name}': contains NaN or infinity")
    r3 = M[3]
    if abs(r3[0]) > 1e-9 or abs(r3[1]) > 1e-9 or abs(r3[2]) > 1e-9 or abs(r3[3] - 1) > 1e-9:
        raise BadLine(f"field '{name}': last row {r3.tolist()} is not [0, 0, 0, 1]")
    A = np.abs(M[:3])
    if A[:, 3].max() > _MAX_TRANS_MM:
        raise BadLine(f"field '{name}': translation beyond {_MAX_TRANS_MM:.0e} mm")
    R = M[:3, :3]
    # entries of a rotation are within [-1, 1]; checking first keeps the products finite
    if A[:, :3].max() > 1 + 1e-3 or np.abs(R @ R.T - _EYE3).max() > _RIGID_TOL:
        raise BadLine(f"field '{name}': not a rigid transform (rotation block not orthonormal)")
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    if abs(a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) - 1) > _RIGID_TOL:
        raise BadLine(f"field '{name}': not a rigid transform (a reflection, det ≠ 1)")
    return M


def _count(x: Any) -> bool:
    return type(x) is int and 0 <= x <= _MAX_COUNT


def validate_header(obj: Any) -> dict[str, Any]:
    """The header object of a session line, checked (format, version, units mm, bodies,
    truth); ``BadLine`` naming the field otherwise."""
    if not isinstance(obj, dict):
        raise BadLine("the header must be a JSON object")
    if obj.get("kind") != "header" or obj.get("format") != FORMAT:
        raise BadLine(f"not a tmscal session header (expected kind 'header' and format '{FORMAT}')")
    v = obj.get("version")
    if type(v) is not int or v != VERSION:
        raise BadLine(f"unsupported session version {v!r} (this tmscal reads version {VERSION})")
    units = obj.get("units", {})
    if not isinstance(units, dict) or units.get("length") != "mm":
        raise BadLine("field 'units.length' must be 'mm'")
    bodies = obj.get("bodies")
    if (not isinstance(bodies, list) or not bodies
            or not all(isinstance(b, str) and b for b in bodies)
            or len(set(bodies)) != len(bodies)):
        raise BadLine("field 'bodies' must be a non-empty list of distinct names")
    for k in ("config", "devices", "plan", "sampling", "units", "adaptive"):
        if k in obj and not isinstance(obj[k], dict):
            raise BadLine(f"field '{k}' must be an object")
    if "created" in obj and not isinstance(obj["created"], str):
        raise BadLine("field 'created' must be a string")
    t = obj.get("truth")
    if t is not None:
        validate_truth(t)
    return obj


def validate_truth(t: Any) -> dict[str, np.ndarray]:
    """The header's ``truth`` (X, Z and optionally Y: 4×4 mm) as arrays; ``BadLine`` naming
    the field otherwise."""
    if not isinstance(t, dict):
        raise BadLine("field 'truth' must be an object")
    extra = [k for k in t if k not in _TRUTH_KEYS]
    if extra:
        raise BadLine(f"field 'truth': unknown key {extra[0]!r} (expected X, Y, Z)")
    out = {}
    for k in _TRUTH_KEYS:
        M = _matrix(t.get(k), f"truth.{k}")
        if M is None and k != "Y":
            raise BadLine(f"field 'truth.{k}' is missing")
        if M is not None:
            out[k] = M
    return out


def validate_pose(obj: Any) -> PoseRecord:
    """A pose line's object as a ``PoseRecord`` (A, B, C: 4×4 mm), checked field by field;
    ``BadLine`` naming the field otherwise."""
    if not isinstance(obj, dict):
        raise BadLine("a pose line must be a JSON object")
    if obj.get("kind") != "pose":
        raise BadLine(f"field 'kind' is {str(obj.get('kind'))[:40]!r}, expected 'pose'")
    idx = obj.get("index")
    if not _count(idx):
        raise BadLine(f"field 'index' must be an integer from 0 to {_MAX_COUNT}")
    mats = {k: _matrix(obj.get(k), k) for k in _MATRIX_KEYS}
    skipped = obj.get("skipped")
    if skipped is not None and not isinstance(skipped, str):
        raise BadLine("field 'skipped' must be a string")
    if skipped is None and mats["A"] is None:
        raise BadLine("field 'A' is missing (and the pose is not skipped)")
    t = obj.get("time", 0.0)
    if not _is_number(t):
        raise BadLine("field 'time' must be a number")
    try:
        t = float(t)
    except OverflowError:
        t = math.inf
    if not math.isfinite(t):
        raise BadLine("field 'time' must be a finite number")
    samples = obj.get("samples", {})
    if not isinstance(samples, dict) or not all(_count(v) for v in samples.values()):
        raise BadLine(f"field 'samples' must be an object of counts (integers 0 to {_MAX_COUNT})")
    spread = obj.get("spread", {})
    if not isinstance(spread, dict) or not all(
            isinstance(v, dict) and all(_is_number(x) and abs(x) < 1e300 for x in v.values())
            for v in spread.values()):
        raise BadLine("field 'spread' must be an object of {\"trans_mm\": mm, \"rot_deg\": deg} "
                   "objects (finite numbers)")
    pool = obj.get("pool")
    if pool is not None and not _count(pool):
        raise BadLine(f"field 'pool' must be an integer from 0 to {_MAX_COUNT}")
    robot_s = obj.get("robot_s")
    if robot_s is not None and not (isinstance(robot_s, dict) and all(
            _is_number(v) and 0 <= v < 1e9 for v in robot_s.values())):
        raise BadLine("field 'robot_s' must be an object of seconds (finite numbers ≥ 0)")
    joints = _numbers(obj.get("joints_rad"), "joints_rad", "joint angles (rad)", _MAX_JOINTS,
                      _MAX_JOINT_RAD)
    wrench = _numbers(obj.get("wrench"), "wrench", "[Fx, Fy, Fz N, Tx, Ty, Tz N·m]", 6,
                      _MAX_WRENCH, exact=True)
    wspread = _numbers(obj.get("wrench_spread"), "wrench_spread",
                       "spreads [N, N, N, N·m, N·m, N·m] ≥ 0", 6, _MAX_WRENCH, exact=True,
                       nonneg=True)
    return PoseRecord(index=idx, time=t, samples=samples, spread=spread, skipped=skipped,
                      pool=pool, robot_s=robot_s, joints_rad=joints, wrench=wrench,
                      wrench_spread=wspread, **mats)


#: at most this many joint angles per pose (DENSO's CurJnt carries up to 32 axes)
_MAX_JOINTS = 32
#: a joint angle beyond ±1000 rad, a force or torque beyond 10⁶ N or N·m is corruption
_MAX_JOINT_RAD = 1e3
_MAX_WRENCH = 1e6


def _numbers(value: Any, name: str, what: str, n: int, bound: float, exact: bool = False,
             nonneg: bool = False) -> list[float] | None:
    """An optional list of finite numbers (None for an absent field or null): exactly ``n``
    with ``exact``, else 1 to ``n``; each of magnitude below ``bound`` (and ≥ 0 with
    ``nonneg``)."""
    if value is None:
        return None
    count = f"{n}" if exact else f"1 to {n}"
    if not (type(value) is list and (len(value) == n if exact else 1 <= len(value) <= n)
            and all(_is_number(x) for x in value)):
        raise BadLine(f"field '{name}': expected a list of {count} numbers ({what})")
    out = []
    for x in value:
        try:
            f = float(x)
        except OverflowError:
            f = math.inf
        if not (math.isfinite(f) and abs(f) < bound) or (nonneg and f < 0):
            raise BadLine(f"field '{name}': {str(x)[:40]} is out of range (a finite number"
                       f"{' ≥ 0' if nonneg else ''} of magnitude below {bound:g})")
        out.append(f)
    return out


@dataclass
class PoseRecord:
    """One pose of a session: A = base_from_flange, B = tracker_from_marker,
    C = tracker_from_probe (4×4 mm or None), the commanded base_from_flange (4×4 mm), the
    time (s since the session started), sample counts, spreads (mm, deg), and ``skipped``
    (the reason) for a pose that is not usable. Adaptive runs (docs/adaptive.md) also record
    ``pool``, the index of the commanded pose in the run's candidate pool, and ``robot_s``,
    the robot time the pose took by phase ({"moving", "settling", "sampling"}: s); both are
    optional and absent from other sessions. ``joints_rad``: the robot's joint angles at the
    pose (rad, as many as it has), when its driver reports them; ``wrench``: the averaged
    force-torque reading [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame, and
    ``wrench_spread`` its standard deviation per channel (same units), for a session with a
    force-torque sensor (docs/selfcal.md). All three are optional; a session without them
    reads as before."""

    index: int
    A: np.ndarray | None
    B: np.ndarray | None
    C: np.ndarray | None = None
    commanded: np.ndarray | None = None
    time: float = 0.0
    samples: dict[str, int] = field(default_factory=dict)
    spread: dict[str, Any] = field(default_factory=dict)
    skipped: str | None = None
    pool: int | None = None
    robot_s: dict[str, float] | None = None
    joints_rad: list[float] | None = None
    wrench: list[float] | None = None
    wrench_spread: list[float] | None = None

    def to_json(self) -> dict[str, Any]:
        """The session line for this pose (matrices as nested lists, mm)."""
        d: dict[str, Any] = {"kind": "pose", "index": int(self.index), "time": float(self.time)}
        for k in _MATRIX_KEYS:
            v = getattr(self, k)
            d[k] = None if v is None else np.asarray(v, dtype=float).tolist()
        d["samples"] = dict(self.samples)
        d["spread"] = self.spread
        if self.skipped:
            d["skipped"] = self.skipped
        if self.pool is not None:
            d["pool"] = int(self.pool)
        if self.robot_s is not None:
            d["robot_s"] = {str(k): float(v) for k, v in self.robot_s.items()}
        for k in ("joints_rad", "wrench", "wrench_spread"):
            v = getattr(self, k)
            if v is not None:
                try:
                    d[k] = np.asarray(v, dtype=np.float64).tolist()
                except (TypeError, ValueError, OverflowError) as e:
                    raise ValueError(f"field '{k}': not a list of numbers ({e})") from None
        return d


#: the wording of ``acquisition.sample``'s problem for a body with too few usable frames
_UNSEEN = re.compile(r"(\w+) usable in \d+ of \d+ frames")


def skip_cause(reason: str) -> str:
    """A short cause for a skipped pose's ``reason`` (``PoseRecord.skipped``): the bodies not
    seen well enough ("probe not seen (missing or out of volume)"), else the reason up to its
    first parenthesis (e.g. "invalid measurement")."""
    bodies = _UNSEEN.findall(reason)
    if bodies:
        return f"{' and '.join(bodies)} not seen (missing or out of volume)"
    return reason.split(" (", 1)[0].strip() or "skipped"


def validate_record(rec: PoseRecord, where: str = "") -> PoseRecord:
    """Check ``rec`` exactly as ``read_session`` will check its line: finite rigid 4×4 mm
    matrices with last row [0, 0, 0, 1], an index from 0 to 10⁹, a finite time, counts and
    spreads that are JSON numbers (no NaN). Returns the record as it will read back; raises
    SessionError naming ``where``, the pose index and the field. Writes nothing."""
    return record_line(rec, where)[1]


def record_line(rec: PoseRecord, where: str = "") -> tuple[bytes, PoseRecord]:
    """The exact bytes of a record's line and the record as the reader will see it."""
    pre = f"{where}: pose {getattr(rec, 'index', '?')}" if where else \
        f"pose {getattr(rec, 'index', '?')}"
    try:
        d = rec.to_json()
    except (TypeError, ValueError, OverflowError) as e:
        raise SessionError(f"{pre}: cannot be stored ({e})") from None
    try:
        # field by field first, so that the message names the field
        norm = {}
        for k, v in d.items():
            if k in _MATRIX_KEYS:
                _matrix(v, k)  # NaN, shape, rigidity
                norm[k] = v
                continue
            try:
                norm[k] = parse_json(_dumps(v))
            except (TypeError, ValueError, OverflowError, RecursionError) as e:
                raise BadLine(f"field '{k}' is not storable as JSON ({e})") from None
            except BadLine as e:
                raise BadLine(f"field '{k}': {e}") from None
        validate_pose(norm)
        # then the whole line, exactly as the reader will read it
        try:
            text = _dumps(d)
        except (TypeError, ValueError, OverflowError, RecursionError) as e:
            raise BadLine(f"not storable as JSON ({e})") from None
        back = validate_pose(parse_json(text))
    except BadLine as e:
        raise SessionError(f"{pre}: {e}") from None
    return text.encode("utf-8") + b"\n", back


def header_line(header: Mapping[str, Any], where: str) -> bytes:
    """The exact bytes of the header line, validated as the reader will validate it."""
    try:
        h = dict(header)
        for k, v in h.items():  # field by field first, so that the message names the field
            if k == "truth" and isinstance(v, dict):
                validate_truth(v)  # NaN in a matrix: say which
            try:
                _dumps(v)
            except (TypeError, ValueError, OverflowError, RecursionError) as e:
                raise BadLine(f"field '{k}' is not storable as JSON ({e})") from None
        try:
            text = _dumps(h)
        except (TypeError, ValueError, OverflowError, RecursionError) as e:
            raise BadLine(f"not storable as JSON ({e})") from None
        validate_header(parse_json(text))
    except BadLine as e:
        raise SessionError(f"{where}: {e}") from None
    return text.encode("utf-8") + b"\n"


def make_header(bodies: Iterable[str], config: Mapping[str, Any] | None = None,
                devices: Mapping[str, Any] | None = None,
                truth: Mapping[str, np.ndarray | None] | None = None,
                **extra: Any) -> dict[str, Any]:
    """A v1 header dict. ``truth`` (X, Z and optionally Y as 4×4 mm) is stored for simulated
    sessions. Raises SessionError if the reader would reject the header (e.g. NaN, values
    that are not JSON, no bodies)."""
    h: dict[str, Any] = {
        "kind": "header", "format": FORMAT, "version": VERSION,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "units": {"length": "mm"}, "bodies": list(bodies),
        "config": dict(config or {}), "devices": dict(devices or {}),
    }
    if truth is not None:
        try:
            h["truth"] = {k: np.asarray(v, dtype=float).tolist() for k, v in truth.items()
                          if v is not None}
        except (TypeError, ValueError) as e:
            raise SessionError(f"session header: field 'truth': not numeric ({e})") from None
    h.update(extra)
    header_line(h, "session header")
    return h


def records_from_arrays(A: np.ndarray, B: np.ndarray | None, C: np.ndarray | None = None,
                        commanded: np.ndarray | None = None, samples: int = 1
                        ) -> list[PoseRecord]:
    """PoseRecords (index 0…n−1) from arrays (n, 4, 4) mm, e.g. for simulated sessions."""
    out = []
    for i in range(len(A)):
        s = {"A": samples}
        if B is not None:
            s["B"] = samples
        if C is not None:
            s["C"] = samples
        out.append(PoseRecord(index=i, A=A[i], B=None if B is None else B[i],
                              C=None if C is None else C[i],
                              commanded=None if commanded is None else commanded[i],
                              time=float(i), samples=s))
    return out
