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
from typing import Any, TypeGuard

import numpy as np

from ..errors import SessionError
from .checks import (
    MAX_JOINT_RAD,
    MAX_JOINTS,
    MAX_WRENCH,
    BadLine,
    is_number,
    parse_matrix,
    parse_numbers,
)
from .jsonable import json_default
from .truth import validate_truth

log = logging.getLogger(__name__)

FORMAT = "tmscal-session"
VERSION = 1
_MATRIX_KEYS = ("A", "B", "C", "commanded")
#: sanity bound: an index or count beyond 10⁹ is corruption (translations: ``checks``)
_MAX_COUNT = 10 ** 9
#: a JSON \\u escape of a UTF-16 surrogate (the only way a line can carry a lone surrogate)
_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89abcdefABCDEF]")


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


def _count(x: Any) -> TypeGuard[int]:
    return type(x) is int and 0 <= x <= _MAX_COUNT


def validate_header(obj: Any) -> dict[str, Any]:
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


def validate_pose(obj: Any) -> PoseRecord:
    if not isinstance(obj, dict):
        raise BadLine("a pose line must be a JSON object")
    if obj.get("kind") != "pose":
        raise BadLine(f"field 'kind' is {str(obj.get('kind'))[:40]!r}, expected 'pose'")
    idx = obj.get("index")
    if not _count(idx):
        raise BadLine(f"field 'index' must be an integer from 0 to {_MAX_COUNT}")
    mats = {k: parse_matrix(obj.get(k), k) for k in _MATRIX_KEYS}
    skipped = obj.get("skipped")
    if skipped is not None and not isinstance(skipped, str):
        raise BadLine("field 'skipped' must be a string")
    if skipped is None and mats["A"] is None:
        raise BadLine("field 'A' is missing (and the pose is not skipped)")
    t = obj.get("time", 0.0)
    if not is_number(t):
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
            isinstance(v, dict) and all(is_number(x) and abs(x) < 1e300 for x in v.values())
            for v in spread.values()):
        raise BadLine("field 'spread' must be an object of {\"trans_mm\": mm, \"rot_deg\": deg} "
                   "objects (finite numbers)")
    pool = obj.get("pool")
    if pool is not None and not _count(pool):
        raise BadLine(f"field 'pool' must be an integer from 0 to {_MAX_COUNT}")
    robot_s = obj.get("robot_s")
    if robot_s is not None and not (isinstance(robot_s, dict) and all(
            is_number(v) and 0 <= v < 1e9 for v in robot_s.values())):
        raise BadLine("field 'robot_s' must be an object of seconds (finite numbers ≥ 0)")
    joints = parse_numbers(obj.get("joints_rad"), "joints_rad", "joint angles (rad)", MAX_JOINTS,
                      MAX_JOINT_RAD)
    wrench = parse_numbers(obj.get("wrench"), "wrench", "[Fx, Fy, Fz N, Tx, Ty, Tz N·m]", 6,
                      MAX_WRENCH, exact=True)
    wspread = parse_numbers(obj.get("wrench_spread"), "wrench_spread",
                       "spreads [N, N, N, N·m, N·m, N·m] ≥ 0", 6, MAX_WRENCH, exact=True,
                       nonneg=True)
    return PoseRecord(index=idx, time=t, samples=samples, spread=spread, skipped=skipped,
                      pool=pool, robot_s=robot_s, joints_rad=joints, wrench=wrench,
                      wrench_spread=wspread, **mats)


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


#: the wording of ``acquisition.sample``'s problem for bodies with too few usable frames:
#: "marker seen in 68 of 100 frames, probe seen in 0 of 100 frames, below min_share 0.9
#: (…)"; sessions of earlier versions say "marker usable in 68 of 100 frames (< 90%: missing
#: or out of volume)" per body
_UNSEEN = re.compile(r"(\w+) (?:usable|seen) in (\d+) of (\d+) frames(?: \(< ([0-9.]+)%)?")
_MIN_SHARE = re.compile(r"below min_share ([0-9.]+)")


def seen_counts(reason: str) -> list[tuple[str, int, int, float | None]]:
    """The bodies a skipped pose's ``reason`` names as seen in too few frames, as (body,
    frames it was usable in, frames read, ``sampling.min_share`` or None when the reason
    does not say), in the reason's order; [] for any other reason."""
    said = _MIN_SHARE.search(reason)
    out = []
    for body, k, n, pct in _UNSEEN.findall(reason):
        limit = float(pct) / 100 if pct else float(said.group(1)) if said else None
        out.append((body, int(k), int(n), limit))
    return out


def skip_cause(reason: str) -> str:
    """A short cause for a skipped pose's ``reason`` (``PoseRecord.skipped``), the same for
    every pose that failed alike (the skip watch and the report count by it): bodies never
    seen, "probe not seen (missing or out of volume)"; bodies seen in some frames but fewer
    than ``sampling.min_share`` of them, "marker and probe seen in too few frames (below
    min_share 0.9)"; else the reason up to its first parenthesis (e.g. "invalid
    measurement")."""
    counts = seen_counts(reason)
    if counts:
        bodies = " and ".join(c[0] for c in counts)
        if all(c[1] == 0 for c in counts):
            return f"{bodies} not seen (missing or out of volume)"
        limits = {c[3] for c in counts if c[3] is not None}
        below = f" (below min_share {min(limits):g})" if limits else ""
        return f"{bodies} seen in too few frames{below}"
    return reason.split(" (", 1)[0].strip() or "skipped"


def seen_text(reason: str) -> str | None:
    """How often each body of a skipped pose's ``reason`` was seen, in short ("marker 68 of
    100 frames, probe 63 of 100"), or None for a reason of another kind."""
    counts = seen_counts(reason)
    if not counts:
        return None
    parts = [f"{b} {k} of {n}" for b, k, n, _ in counts]
    return parts[0] + " frames" + "".join(f", {p}" for p in parts[1:])


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
                parse_matrix(v, k)  # NaN, shape, rigidity
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
                truth: Mapping[str, Any] | None = None,
                **extra: Any) -> dict[str, Any]:
    """A v1 header dict. ``truth`` (X, Z and optionally Y as 4×4 mm, and optionally the
    rig's ``arm``, as ``tmscal.sim.Truth.as_dict`` gives it) is stored for simulated
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
            h["truth"] = {k: (v if k == "arm" else np.asarray(v, dtype=float).tolist())
                          for k, v in truth.items() if v is not None}
        except (TypeError, ValueError) as e:
            raise SessionError(f"session header: field 'truth': not numeric ({e})") from None
    h.update(extra)
    header_line(h, "session header")
    return h


def records_from_arrays(A: np.ndarray, B: np.ndarray | None, C: np.ndarray | None = None,
                        commanded: np.ndarray | None = None, samples: int = 1,
                        joints: np.ndarray | None = None) -> list[PoseRecord]:
    """PoseRecords (index 0…n−1) from arrays (n, 4, 4) mm, e.g. for simulated sessions;
    ``joints`` (n, k) rad: each pose's ``joints_rad``."""
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
                              time=float(i), samples=s,
                              joints_rad=None if joints is None else list(joints[i])))
    return out
