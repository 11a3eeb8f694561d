"""An external measurement campaign as a tmscal session (``tmscal import``; docs/kinematics.md,
"Laser trackers and 6D probes"): a CSV of the robot's joints and, per row, the pose of a target
on the flange that an external instrument measured — a laser tracker's 6D probe (Leica T-Mac,
its position and orientation) or three reflectors (a FARO or Leica tracker's three points, from
which the frame is built) — read into a marker-only session (A X = Z B; Zhuang, Roth and
Sudhakar 1994), so that ``tmscal solve --kinematics estimate`` calibrates the arm on it.

Frames and units: B = tracker ← target (4×4, mm), the instrument's measurement; A =
base ← flange (4×4, mm), the NOMINAL forward kinematics of the recorded joints of the arm
named (what the controller would report; the registry's model, docs/kinematics.md); joints
rad. Columns (:class:`Columns`):

* ``joints``: one column per joint, in the chain's order, ``joint_unit`` rad or deg;
* a 6D pose: ``position`` (3 columns, ``length_unit`` mm or m) and ``rotation`` (3 or 4
  columns) of ``rotation_kind``: ``euler:SEQ`` (scipy's convention: upper-case SEQ intrinsic
  axes, e.g. ``euler:XYZ``, lower-case extrinsic), ``quat:xyzw`` / ``quat:wxyz`` (unit
  quaternion, scalar last or first), ``rotvec`` (rotation vector); angles in ``angle_unit``
  deg or rad;
* or ``points``: 9 columns, three reflectors p1, p2, p3 (x, y, z each, ``length_unit``) on
  the flange, none two at one place, not on one line: the frame has its origin at p1, x
  towards p2, z along x × (p3 − p1), y = z × x (any three fixed points give a rigid frame on
  the flange; X, the hand/eye, absorbs where it is).

Numbers may use a decimal comma (``decimal=","``, as spreadsheets of some locales write, with
``;`` between fields). Every problem is one :class:`~tmscal.errors.SessionError` naming the
file, the line and the column.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..calib.kinematics.model import Arm, base_from_flange
from ..errors import SessionError
from ..filekind import read_kind
from ..geometry import make_pose
from ..session import PoseRecord, make_header

__all__ = ["Columns", "Campaign", "ROTATION_KINDS", "read_campaign", "campaign_records",
           "campaign_header", "frame_from_points", "MAX_ROWS", "MAX_BYTES"]

#: the rotation columns' kinds (module docstring)
ROTATION_KINDS = ("euler:SEQ", "quat:xyzw", "quat:wxyz", "rotvec")
#: rows read at most (a 10,000-pose campaign is an ordinary job; this bounds a wrong file)
MAX_ROWS = 200_000
#: the largest CSV read (bytes)
MAX_BYTES = 64_000_000
#: |value| beyond which a number is refused (mm, rad or deg: a typo, not a measurement)
_BOUND = 1e7
#: reflectors closer than this (mm), or a triangle flatter than this (sine of its angle), give
#: no frame
_MIN_SPAN_MM, _MIN_SINE = 1.0, 1e-3


@dataclass(frozen=True)
class Columns:
    """Which CSV columns hold what (module docstring): ``joints`` (one name per joint),
    either ``position`` (3) and ``rotation`` (3 or 4) with ``rotation_kind``, or ``points``
    (9); the units ``joint_unit`` (rad, deg), ``length_unit`` (mm, m), ``angle_unit`` (deg,
    rad). Raises SessionError for an inconsistent choice."""

    joints: tuple[str, ...]
    position: tuple[str, ...] = ()
    rotation: tuple[str, ...] = ()
    rotation_kind: str = "euler:XYZ"
    points: tuple[str, ...] = ()
    joint_unit: str = "rad"
    length_unit: str = "mm"
    angle_unit: str = "deg"

    def __post_init__(self) -> None:
        def bad(msg: str) -> SessionError:
            return SessionError(f"import: {msg}")
        if not self.joints:
            raise bad("name the joint columns (joints=)")
        for key, val, allowed in (("joint_unit", self.joint_unit, ("rad", "deg")),
                                  ("length_unit", self.length_unit, ("mm", "m")),
                                  ("angle_unit", self.angle_unit, ("deg", "rad"))):
            if val not in allowed:
                raise bad(f"{key} must be {' or '.join(allowed)}, got {val!r}")
        if bool(self.points) == bool(self.position or self.rotation):
            raise bad("give either the 6D pose (position= and rotation=) or the three points "
                      "(points=), not both and not neither")
        if self.points and len(self.points) != 9:
            raise bad(f"points= takes 9 columns (p1 x, y, z, p2 …, p3 …), got "
                      f"{len(self.points)}")
        if not self.points:
            if len(self.position) != 3:
                raise bad(f"position= takes 3 columns (x, y, z), got {len(self.position)}")
            n_rot = 4 if self.rotation_kind.startswith("quat:") else 3
            if not _known_kind(self.rotation_kind):
                raise bad(f"rotation_kind must be one of {', '.join(ROTATION_KINDS)} (SEQ "
                          f"three of x, y, z, all upper case or all lower case), got "
                          f"{self.rotation_kind!r}")
            if len(self.rotation) != n_rot:
                raise bad(f"rotation= takes {n_rot} columns for {self.rotation_kind}, got "
                          f"{len(self.rotation)}")
        names = self.used()
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise bad(f"a column is named twice: {', '.join(dup)}")

    def used(self) -> list[str]:
        """Every column these columns read, in order."""
        return [*self.joints, *self.position, *self.rotation, *self.points]

    def record(self) -> dict[str, Any]:
        """The mapping as the session header keeps it (``import.columns``)."""
        out: dict[str, Any] = {"joints": list(self.joints), "joint_unit": self.joint_unit,
                               "length_unit": self.length_unit}
        if self.points:
            out["points"] = list(self.points)
        else:
            out.update(position=list(self.position), rotation=list(self.rotation),
                       rotation_kind=self.rotation_kind, angle_unit=self.angle_unit)
        return out


def _known_kind(kind: str) -> bool:
    if kind in ("quat:xyzw", "quat:wxyz", "rotvec"):
        return True
    if not kind.startswith("euler:"):
        return False
    seq = kind[6:]
    return len(seq) == 3 and (set(seq) <= set("xyz") or set(seq) <= set("XYZ"))


@dataclass
class Campaign:
    """What :func:`read_campaign` read: ``q`` (n, joints) rad, ``B`` (n, 4, 4) mm tracker ←
    target, ``lines`` the CSV line of each row (1 = the header), ``sha256`` of the file."""

    path: Path
    q: np.ndarray
    B: np.ndarray
    lines: list[int]
    sha256: str


def _number(text: str, decimal: str, where: str) -> float:
    t = text.strip()
    if decimal == ",":
        t = t.replace(".", "").replace(",", ".") if t.count(",") == 1 and "." in t else \
            t.replace(",", ".")
    try:
        v = float(t)
    except ValueError:
        raise SessionError(f"{where}: {text.strip()[:40]!r} is not a number") from None
    if not math.isfinite(v) or abs(v) > _BOUND:
        raise SessionError(f"{where}: {text.strip()[:40]!r} is not a finite number within "
                           f"±{_BOUND:g}")
    return v


def frame_from_points(p: np.ndarray) -> np.ndarray:
    """The frame (4×4 mm, tracker ← target) of three reflectors ``p`` (3, 3) mm (rows p1, p2,
    p3): origin p1, x towards p2, z along x × (p3 − p1), y = z × x. ValueError when two
    points coincide (closer than 1 mm) or the three are on one line."""
    p = np.asarray(p, dtype=float).reshape(3, 3)
    a, b = p[1] - p[0], p[2] - p[0]
    la, lb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if min(la, lb, float(np.linalg.norm(p[2] - p[1]))) < _MIN_SPAN_MM:
        raise ValueError("two of the three points are at one place")
    z = np.cross(a, b)
    if np.linalg.norm(z) < _MIN_SINE * la * lb:
        raise ValueError("the three points are on one line")
    x = a / la
    z = z / np.linalg.norm(z)
    return make_pose(np.column_stack([x, np.cross(z, x), z]), p[0])


def _rotation(vals: np.ndarray, cols: Columns) -> np.ndarray:
    kind = cols.rotation_kind
    if kind.startswith("quat:"):
        q = vals if kind == "quat:xyzw" else vals[[1, 2, 3, 0]]
        n = float(np.linalg.norm(q))
        if abs(n - 1.0) > 1e-3:
            raise ValueError(f"the quaternion's norm is {n:.6g}, not 1")
        return np.asarray(Rotation.from_quat(q / n).as_matrix())
    deg = cols.angle_unit == "deg"
    if kind == "rotvec":
        return np.asarray(Rotation.from_rotvec(np.radians(vals) if deg else vals).as_matrix())
    return np.asarray(Rotation.from_euler(kind[6:], vals, degrees=deg).as_matrix())


def read_campaign(path: str | Path, cols: Columns, delimiter: str | None = None,
                  decimal: str = ".") -> Campaign:
    """Read a campaign CSV (module docstring) with a header line naming the columns;
    ``delimiter`` None: guessed from the header (``;``, ``,`` or a tab). Rows are kept in file
    order. Raises SessionError naming the file, line and column."""
    p = Path(path)
    text = read_kind(p, "measurements", "measurement CSV", MAX_BYTES, SessionError)
    if decimal not in (".", ","):
        raise SessionError(f"import: decimal must be '.' or ',', got {decimal!r}")
    first = text.split("\n", 1)[0]
    if delimiter is None:
        delimiter = max((";", ",", "\t"), key=first.count)
    if delimiter == decimal:
        raise SessionError(f"{p}: the field delimiter and the decimal mark are both "
                           f"{delimiter!r}; give decimal=',' with delimiter=';'")
    reader = csv.reader(io.StringIO(text), delimiter=delimiter)
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise SessionError(f"{p}: empty file (expected a header line naming the columns)"
                           ) from None
    pos = {h: i for i, h in enumerate(header)}
    missing = [c for c in cols.used() if c not in pos]
    if missing:
        raise SessionError(f"{p}: line 1: no column {', '.join(map(repr, missing))} (the "
                           f"header has {', '.join(header[:30])}"
                           f"{', …' if len(header) > 30 else ''})")
    idx = [pos[c] for c in cols.used()]
    qs: list[np.ndarray] = []
    Bs: list[np.ndarray] = []
    lines: list[int] = []
    nj, npos, nrot = len(cols.joints), len(cols.position), len(cols.rotation)
    scale_l = 1000.0 if cols.length_unit == "m" else 1.0
    for row in reader:
        line = reader.line_num
        if not row or all(not f.strip() for f in row):
            continue
        if len(lines) >= MAX_ROWS:
            raise SessionError(f"{p}: more than {MAX_ROWS} rows")
        vals = []
        for c, i in zip(cols.used(), idx, strict=True):
            if i >= len(row):
                raise SessionError(f"{p}: line {line}: column {c!r}: missing (the row has "
                                   f"{len(row)} fields, the header {len(header)})")
            vals.append(_number(row[i], decimal, f"{p}: line {line}: column {c!r}"))
        v = np.array(vals)
        q = v[:nj] if cols.joint_unit == "rad" else np.radians(v[:nj])
        try:
            if cols.points:
                B = frame_from_points(v[nj:].reshape(3, 3) * scale_l)
            else:
                B = make_pose(_rotation(v[nj + npos:nj + npos + nrot], cols),
                              v[nj:nj + npos] * scale_l)
        except ValueError as e:
            what = "points" if cols.points else "rotation"
            raise SessionError(f"{p}: line {line}: columns {what}=: {e}") from None
        qs.append(q)
        Bs.append(B)
        lines.append(line)
    if len(lines) < 3:
        raise SessionError(f"{p}: {len(lines)} rows of data; a calibration needs at least 3")
    return Campaign(path=p, q=np.array(qs), B=np.array(Bs), lines=lines,
                    sha256=hashlib.sha256(text.encode()).hexdigest())


def campaign_records(c: Campaign, arm: Arm) -> list[PoseRecord]:
    """One pose per row: A the nominal forward kinematics of ``arm`` at the row's joints
    (base ← flange, mm), B the measured target (tracker ← target, mm), the joints. Raises
    SessionError when the rows' joint count is not the arm's."""
    if c.q.shape[1] != arm.n_joints:
        raise SessionError(f"{c.path}: {c.q.shape[1]} joint columns; arm {arm.name} has "
                           f"{arm.n_joints} joints")
    A = base_from_flange(arm, c.q)
    return [PoseRecord(index=i, A=A[i], B=c.B[i], commanded=A[i], time=float(i),
                       samples={"A": 1, "B": 1}, joints_rad=[float(x) for x in c.q[i]])
            for i in range(len(c.q))]


def campaign_header(c: Campaign, arm: Arm, cols: Columns, instrument: str) -> dict[str, Any]:
    """The session header: a marker-only session (the target is the "marker"), the robot
    ``devices.robot.arm`` (the registry name ``solve --kinematics estimate`` takes), the
    instrument, and ``import`` {source, sha256, lines, columns}."""
    return make_header(["marker"], devices={
        "robot": {"driver": "import", "arm": arm.name},
        "tracker": {"driver": "import", "model": instrument}},
        **{"import": {"source": c.path.name, "sha256": c.sha256,
                      "lines": [c.lines[0], c.lines[-1]], "rows": len(c.lines),
                      "columns": cols.record()}})
