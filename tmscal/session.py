"""Session files: the contract between ``tmscal acquire`` and ``tmscal solve`` (format v1).

One JSON Lines file, UTF-8. Line 1 is the header::

    {"kind": "header", "format": "tmscal-session", "version": 1, "created": ISO-8601,
     "units": {"length": "mm"}, "bodies": ["marker", "probe"], "config": {...},
     "devices": {...}, ["truth": {"X": 4×4, "Y": 4×4, "Z": 4×4}], ["plan": {...}]}

then one line per pose, appended, flushed and fsynced::

    {"kind": "pose", "index": i, "time": s, "A": 4×4, "B": 4×4|null, "C": 4×4|null,
     "commanded": 4×4, "samples": {"A": n, "B": n, "C": n}, "spread": {...},
     ["skipped": "reason"]}

Matrices are nested lists, row by row, in mm: A = base_from_flange, B = tracker_from_marker,
C = tracker_from_probe. Readers ignore a torn last line (and say so), reject anything else
that is malformed with the file, line number and field, and accept marker-only sessions.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import logging
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import SessionError

log = logging.getLogger(__name__)

FORMAT = "tmscal-session"
VERSION = 1
_MATRIX_KEYS = ("A", "B", "C", "commanded")


def _matrix(value: Any, where: str, rigid_tol: float = 1e-4) -> np.ndarray | None:
    if value is None:
        return None
    try:
        M = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SessionError(f"{where}: not a numeric 4×4 matrix") from None
    if M.shape != (4, 4):
        raise SessionError(f"{where}: expected a 4×4 matrix, got shape {M.shape}")
    if not np.isfinite(M).all():
        raise SessionError(f"{where}: contains NaN or infinity")
    if np.abs(M[3] - (0, 0, 0, 1)).max() > 1e-9:
        raise SessionError(f"{where}: last row {M[3].tolist()} is not [0, 0, 0, 1]")
    R = M[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > rigid_tol or abs(np.linalg.det(R) - 1) > rigid_tol:
        raise SessionError(f"{where}: not a rigid transform (rotation block not orthonormal)")
    return M


@dataclass
class PoseRecord:
    """One pose of a session: A, B, C (4×4 mm or None), commanded pose, bookkeeping."""

    index: int
    A: np.ndarray | None
    B: np.ndarray | None
    C: np.ndarray | None = None
    commanded: np.ndarray | None = None
    time: float = 0.0
    samples: dict[str, int] = field(default_factory=dict)
    spread: dict[str, Any] = field(default_factory=dict)
    skipped: str | None = None

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
        return d


@dataclass
class Session:
    """A session read from disk: ``header`` (dict), ``poses`` (list of PoseRecord, file order),
    ``path``, ``torn_tail`` (True when a torn last line was ignored) and ``good_bytes`` (the
    length of the valid prefix, for resuming)."""

    header: dict[str, Any]
    poses: list[PoseRecord]
    path: Path | None = None
    torn_tail: bool = False
    good_bytes: int = 0

    @property
    def bodies(self) -> list[str]:
        """Tracked body names from the header, e.g. ["marker", "probe"]."""
        return list(self.header.get("bodies", []))

    @property
    def truth(self) -> dict[str, np.ndarray] | None:
        """Ground truth {"X", "Y", "Z"} (4×4 mm) when the session was simulated, else None."""
        t = self.header.get("truth")
        if not t:
            return None
        return {k: np.asarray(v, dtype=float) for k, v in t.items() if v is not None}

    def indices(self) -> set[int]:
        """Pose indices recorded so far (skipped poses included)."""
        return {p.index for p in self.poses}

    def arrays(self, need_probe: bool = False) -> tuple[np.ndarray, np.ndarray,
                                                        np.ndarray | None, list[int]]:
        """(A, B, C, indices) of the usable poses, ordered by pose index: poses with A and B
        (and C when ``need_probe``); C is None when no usable pose has one. (n, 4, 4) mm."""
        use = [p for p in sorted(self.poses, key=lambda p: p.index)
               if p.skipped is None and p.A is not None and p.B is not None
               and (p.C is not None or not need_probe)]
        if not use:
            return np.zeros((0, 4, 4)), np.zeros((0, 4, 4)), None, []
        A = np.stack([p.A for p in use])
        B = np.stack([p.B for p in use])
        has_c = all(p.C is not None for p in use)
        C = np.stack([p.C for p in use]) if has_c else None
        return A, B, C, [p.index for p in use]


def make_header(bodies: Iterable[str], config: Mapping[str, Any] | None = None,
                devices: Mapping[str, Any] | None = None,
                truth: Mapping[str, np.ndarray | None] | None = None,
                **extra: Any) -> dict[str, Any]:
    """A v1 header dict. ``truth`` (X, Y, Z as 4×4 mm) is stored for simulated sessions."""
    h: dict[str, Any] = {
        "kind": "header", "format": FORMAT, "version": VERSION,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "units": {"length": "mm"}, "bodies": list(bodies),
        "config": dict(config or {}), "devices": dict(devices or {}),
    }
    if truth is not None:
        h["truth"] = {k: np.asarray(v, dtype=float).tolist() for k, v in truth.items()
                      if v is not None}
    h.update(extra)
    return h


def _parse_header(obj: Any, where: str) -> dict[str, Any]:
    if not isinstance(obj, dict):
        raise SessionError(f"{where}: the header must be a JSON object")
    if obj.get("kind") != "header" or obj.get("format") != FORMAT:
        raise SessionError(f"{where}: not a tmscal session header "
                           f"(expected kind 'header' and format '{FORMAT}')")
    if obj.get("version") != VERSION:
        raise SessionError(f"{where}: unsupported session version {obj.get('version')!r} "
                           f"(this tmscal reads version {VERSION})")
    units = obj.get("units", {})
    if not isinstance(units, dict) or units.get("length") != "mm":
        raise SessionError(f"{where}: field 'units.length' must be 'mm'")
    bodies = obj.get("bodies")
    if not isinstance(bodies, list) or not bodies or not all(isinstance(b, str) for b in bodies):
        raise SessionError(f"{where}: field 'bodies' must be a non-empty list of names")
    if "truth" in obj and obj["truth"] is not None:
        if not isinstance(obj["truth"], dict):
            raise SessionError(f"{where}: field 'truth' must be an object")
        for k, v in obj["truth"].items():
            _matrix(v, f"{where}: field 'truth.{k}'")
    return obj


def _parse_pose(obj: Any, where: str) -> PoseRecord:
    if not isinstance(obj, dict):
        raise SessionError(f"{where}: a pose line must be a JSON object")
    if obj.get("kind") != "pose":
        raise SessionError(f"{where}: field 'kind' is {obj.get('kind')!r}, expected 'pose'")
    idx = obj.get("index")
    if not isinstance(idx, int) or isinstance(idx, bool) or idx < 0:
        raise SessionError(f"{where}: field 'index' must be a non-negative integer")
    mats = {k: _matrix(obj.get(k), f"{where}: field '{k}'") for k in _MATRIX_KEYS}
    skipped = obj.get("skipped")
    if skipped is not None and not isinstance(skipped, str):
        raise SessionError(f"{where}: field 'skipped' must be a string")
    if skipped is None and mats["A"] is None:
        raise SessionError(f"{where}: field 'A' is missing (and the pose is not skipped)")
    t = obj.get("time", 0.0)
    if not isinstance(t, int | float) or isinstance(t, bool):
        raise SessionError(f"{where}: field 'time' must be a number")
    samples = obj.get("samples", {})
    spread = obj.get("spread", {})
    if not isinstance(samples, dict) or not isinstance(spread, dict):
        raise SessionError(f"{where}: fields 'samples' and 'spread' must be objects")
    return PoseRecord(index=idx, time=float(t), samples=samples, spread=spread,
                      skipped=skipped, **mats)


def read_session(path: str | os.PathLike[str]) -> Session:
    """Read and validate a session file. Raises SessionError naming the file, the line and
    the field; a torn last line (no newline, not valid JSON) is ignored with a warning."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise SessionError(f"{p}: cannot read session file ({e.strerror or e})") from None
    if not data.strip():
        raise SessionError(f"{p}: empty file, not a tmscal session")
    lines = data.split(b"\n")
    ends_with_newline = data.endswith(b"\n")
    if ends_with_newline:
        lines = lines[:-1]
    header: dict[str, Any] | None = None
    poses: list[PoseRecord] = []
    seen: dict[int, int] = {}
    torn = False
    offset = 0
    good = 0
    for no, raw in enumerate(lines, start=1):
        last = no == len(lines)
        where = f"{p}, line {no}"
        line_len = len(raw) + (1 if (not last or ends_with_newline) else 0)
        try:
            text = raw.decode("utf-8")
            obj = json.loads(text)
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            if last and not ends_with_newline and header is not None:
                log.warning("%s: torn last line ignored (an interrupted write)", where)
                torn = True
                break
            raise SessionError(f"{where}: not valid JSON ({e})") from None
        if header is None:
            header = _parse_header(obj, where)
        else:
            rec = _parse_pose(obj, where)
            if rec.index in seen:
                raise SessionError(f"{where}: pose index {rec.index} already on line "
                                   f"{seen[rec.index]}")
            seen[rec.index] = no
            poses.append(rec)
        offset += line_len
        good = offset
    if header is None:
        raise SessionError(f"{p}: no header line")
    return Session(header=header, poses=poses, path=p, torn_tail=torn, good_bytes=good)


class SessionWriter:
    """Append-only session writer: each pose is one line, flushed and fsynced.

    ``SessionWriter.create(path, header)`` starts a new file (refuses to overwrite an
    existing one unless ``overwrite``); ``SessionWriter.resume(path)`` reopens an existing
    session for appending, cutting off a torn last line first. Context manager."""

    def __init__(self, path: Path, fh: Any, session: Session) -> None:
        self.path = path
        self._fh = fh
        self.session = session

    @classmethod
    def create(cls, path: str | os.PathLike[str], header: Mapping[str, Any],
               overwrite: bool = False) -> SessionWriter:
        """Start a new session file with ``header`` (validated); fsynced."""
        p = Path(path)
        if p.exists() and not overwrite:
            raise SessionError(f"{p}: already exists; refusing to overwrite "
                               "(choose another name, or resume it)")
        _parse_header(dict(header), f"{p}: header")
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
            fh = open(p, "wb")
            fh.write(json.dumps(dict(header), separators=(",", ":")).encode() + b"\n")
            fh.flush()
            os.fsync(fh.fileno())
        except OSError as e:
            raise SessionError(f"{p}: cannot write session file ({e.strerror or e})") from None
        return cls(p, fh, Session(header=dict(header), poses=[], path=p))

    @classmethod
    def resume(cls, path: str | os.PathLike[str]) -> SessionWriter:
        """Reopen an existing session for appending; a torn last line is cut off first."""
        p = Path(path)
        s = read_session(p)
        try:
            fh = open(p, "r+b")
            if s.torn_tail:
                fh.truncate(s.good_bytes)
            fh.seek(0, os.SEEK_END)
            if fh.tell() > 0:
                fh.seek(-1, os.SEEK_END)
                if fh.read(1) != b"\n":
                    fh.write(b"\n")
            fh.flush()
            os.fsync(fh.fileno())
        except OSError as e:
            raise SessionError(f"{p}: cannot reopen session for appending "
                               f"({e.strerror or e})") from None
        return cls(p, fh, s)

    def append(self, rec: PoseRecord) -> None:
        """Append one pose line and fsync it."""
        if rec.index in self.session.indices():
            raise SessionError(f"{self.path}: pose index {rec.index} is already recorded")
        line = json.dumps(rec.to_json(), separators=(",", ":")).encode() + b"\n"
        try:
            self._fh.write(line)
            self._fh.flush()
            os.fsync(self._fh.fileno())
        except OSError as e:
            raise SessionError(f"{self.path}: cannot append pose {rec.index} "
                               f"({e.strerror or e})") from None
        self.session.poses.append(rec)

    def close(self) -> None:
        """Close the file (safe twice)."""
        if self._fh is not None and not self._fh.closed:
            self._fh.close()

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_session(path: str | os.PathLike[str], header: Mapping[str, Any],
                  poses: Iterable[PoseRecord], overwrite: bool = False) -> Path:
    """Write a whole session (header + poses) at once; returns the path."""
    with SessionWriter.create(path, header, overwrite=overwrite) as w:
        for rec in poses:
            w.append(rec)
    return Path(path)


def sha256_of(path: str | os.PathLike[str]) -> str:
    """SHA-256 hex digest of a file (for calibration results)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


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
