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
C = tracker_from_probe.

Integrity rules (``docs/session-format.md``):

- The writer validates every line exactly as the reader will before writing it, so what it
  writes can always be read back; a record the reader would reject raises SessionError and
  nothing is written.
- Readers ignore a torn last line (and say so). A damaged line in the middle (not JSON, or JSON
  that fails validation, or a repeated pose index) is skipped with a warning and listed in
  ``Session.damaged``; ``strict=True`` makes it an error instead. A damaged header is always an
  error. Only regular files are read (a FIFO or a directory is refused, never waited on).
- A writer holds an exclusive advisory lock (``flock``) on the file until it is closed, and
  appends with ``O_APPEND``; a second writer is refused.
"""

from __future__ import annotations

import datetime as _dt
import errno
import fcntl
import hashlib
import json
import logging
import math
import os
import re
import stat
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
_TRUTH_KEYS = ("X", "Y", "Z")
#: sanity bounds: a translation beyond 10 km, an index or count beyond 10⁹ is corruption
_MAX_TRANS_MM = 1e7
_MAX_COUNT = 10 ** 9
_RIGID_TOL = 1e-4
#: a JSON \\u escape of a UTF-16 surrogate (the only way a line can carry a lone surrogate)
_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89abcdefABCDEF]")


class _Bad(Exception):
    """A line fails validation; the message is the reason without file and line."""


# --- validation (shared by the reader and the writer) --------------------------------------

def _reject_constant(name: str) -> Any:
    raise ValueError(f"non-finite number {name} (JSON has no NaN or infinity)")


def _finite_float(text: str) -> float:
    x = float(text)
    if not math.isfinite(x):
        raise ValueError(f"number {text[:40]} is out of range (not a finite float64)")
    return x


def _loads(text: str, finite: bool = True) -> Any:
    """json.loads that refuses NaN and Infinity literals and, with ``finite``, numbers that
    overflow float64 anywhere (pose lines skip that slower check: every number the reader
    keeps from them is checked for finiteness field by field)."""
    try:
        obj = json.loads(text, parse_constant=_reject_constant,
                         parse_float=_finite_float if finite else None)
    except RecursionError:
        raise _Bad("not valid JSON (nested too deeply)") from None
    except json.JSONDecodeError as e:
        raise _Bad(f"not valid JSON ({e.msg} at column {e.colno})") from None
    except ValueError as e:  # the int digit limit, our parse hooks
        raise _Bad(f"not valid JSON ({str(e)[:120]})") from None
    if _SURROGATE_ESCAPE.search(text):
        try:
            json.dumps(obj, ensure_ascii=False).encode("utf-8")
        except UnicodeEncodeError:
            raise _Bad("a string holds an unpaired UTF-16 surrogate (not valid Unicode)") \
                from None
    return obj


def _json_default(o: Any) -> Any:
    """numpy scalars and arrays as plain JSON numbers and lists (writer side)."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"{type(o).__name__!r} is not JSON-serialisable")


def _dumps(obj: Any) -> str:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False, default=_json_default)


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
        raise _Bad(f"field '{name}': expected a 4×4 matrix (4 rows of 4 numbers)")
    if not all(_NUMBER_TYPES.issuperset(map(type, r)) for r in value):
        raise _Bad(f"field '{name}': entries must be numbers")
    try:
        M = np.array(value, dtype=np.float64)
    except (OverflowError, ValueError, TypeError):
        raise _Bad(f"field '{name}': a number is out of range") from None
    if not np.isfinite(M).all():
        raise _Bad(f"field '{name}': contains NaN or infinity")
    r3 = M[3]
    if abs(r3[0]) > 1e-9 or abs(r3[1]) > 1e-9 or abs(r3[2]) > 1e-9 or abs(r3[3] - 1) > 1e-9:
        raise _Bad(f"field '{name}': last row {r3.tolist()} is not [0, 0, 0, 1]")
    A = np.abs(M[:3])
    if A[:, 3].max() > _MAX_TRANS_MM:
        raise _Bad(f"field '{name}': translation beyond {_MAX_TRANS_MM:.0e} mm")
    R = M[:3, :3]
    # entries of a rotation are within [-1, 1]; checking first keeps the products finite
    if A[:, :3].max() > 1 + 1e-3 or np.abs(R @ R.T - _EYE3).max() > _RIGID_TOL:
        raise _Bad(f"field '{name}': not a rigid transform (rotation block not orthonormal)")
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    if abs(a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) - 1) > _RIGID_TOL:
        raise _Bad(f"field '{name}': not a rigid transform (a reflection, det ≠ 1)")
    return M


def _count(x: Any) -> bool:
    return type(x) is int and 0 <= x <= _MAX_COUNT


def _check_header(obj: Any) -> dict[str, Any]:
    if not isinstance(obj, dict):
        raise _Bad("the header must be a JSON object")
    if obj.get("kind") != "header" or obj.get("format") != FORMAT:
        raise _Bad(f"not a tmscal session header (expected kind 'header' and format '{FORMAT}')")
    v = obj.get("version")
    if type(v) is not int or v != VERSION:
        raise _Bad(f"unsupported session version {v!r} (this tmscal reads version {VERSION})")
    units = obj.get("units", {})
    if not isinstance(units, dict) or units.get("length") != "mm":
        raise _Bad("field 'units.length' must be 'mm'")
    bodies = obj.get("bodies")
    if (not isinstance(bodies, list) or not bodies
            or not all(isinstance(b, str) and b for b in bodies)
            or len(set(bodies)) != len(bodies)):
        raise _Bad("field 'bodies' must be a non-empty list of distinct names")
    for k in ("config", "devices", "plan", "sampling", "units"):
        if k in obj and not isinstance(obj[k], dict):
            raise _Bad(f"field '{k}' must be an object")
    if "created" in obj and not isinstance(obj["created"], str):
        raise _Bad("field 'created' must be a string")
    t = obj.get("truth")
    if t is not None:
        _check_truth(t)
    return obj


def _check_truth(t: Any) -> dict[str, np.ndarray]:
    if not isinstance(t, dict):
        raise _Bad("field 'truth' must be an object")
    extra = [k for k in t if k not in _TRUTH_KEYS]
    if extra:
        raise _Bad(f"field 'truth': unknown key {extra[0]!r} (expected X, Y, Z)")
    out = {}
    for k in _TRUTH_KEYS:
        M = _matrix(t.get(k), f"truth.{k}")
        if M is None and k != "Y":
            raise _Bad(f"field 'truth.{k}' is missing")
        if M is not None:
            out[k] = M
    return out


def _check_pose(obj: Any) -> PoseRecord:
    if not isinstance(obj, dict):
        raise _Bad("a pose line must be a JSON object")
    if obj.get("kind") != "pose":
        raise _Bad(f"field 'kind' is {str(obj.get('kind'))[:40]!r}, expected 'pose'")
    idx = obj.get("index")
    if not _count(idx):
        raise _Bad(f"field 'index' must be an integer from 0 to {_MAX_COUNT}")
    mats = {k: _matrix(obj.get(k), k) for k in _MATRIX_KEYS}
    skipped = obj.get("skipped")
    if skipped is not None and not isinstance(skipped, str):
        raise _Bad("field 'skipped' must be a string")
    if skipped is None and mats["A"] is None:
        raise _Bad("field 'A' is missing (and the pose is not skipped)")
    t = obj.get("time", 0.0)
    if not _is_number(t):
        raise _Bad("field 'time' must be a number")
    try:
        t = float(t)
    except OverflowError:
        t = math.inf
    if not math.isfinite(t):
        raise _Bad("field 'time' must be a finite number")
    samples = obj.get("samples", {})
    if not isinstance(samples, dict) or not all(_count(v) for v in samples.values()):
        raise _Bad(f"field 'samples' must be an object of counts (integers 0 to {_MAX_COUNT})")
    spread = obj.get("spread", {})
    if not isinstance(spread, dict) or not all(
            isinstance(v, dict) and all(_is_number(x) and abs(x) < 1e300 for x in v.values())
            for v in spread.values()):
        raise _Bad("field 'spread' must be an object of {\"trans_mm\": mm, \"rot_deg\": deg} "
                   "objects (finite numbers)")
    return PoseRecord(index=idx, time=t, samples=samples, spread=spread, skipped=skipped,
                      **mats)


@dataclass
class PoseRecord:
    """One pose of a session: A = base_from_flange, B = tracker_from_marker,
    C = tracker_from_probe (4×4 mm or None), the commanded base_from_flange (4×4 mm), the
    time (s since the session started), sample counts, spreads (mm, deg), and ``skipped``
    (the reason) for a pose that is not usable."""

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


def validate_record(rec: PoseRecord, where: str = "") -> PoseRecord:
    """Check ``rec`` exactly as ``read_session`` will check its line: finite rigid 4×4 mm
    matrices with last row [0, 0, 0, 1], an index from 0 to 10⁹, a finite time, counts and
    spreads that are JSON numbers (no NaN). Returns the record as it will read back; raises
    SessionError naming ``where``, the pose index and the field. Writes nothing."""
    return _line_for(rec, where)[1]


def _line_for(rec: PoseRecord, where: str = "") -> tuple[bytes, PoseRecord]:
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
                norm[k] = _loads(_dumps(v))
            except (TypeError, ValueError, OverflowError, RecursionError) as e:
                raise _Bad(f"field '{k}' is not storable as JSON ({e})") from None
            except _Bad as e:
                raise _Bad(f"field '{k}': {e}") from None
        _check_pose(norm)
        # then the whole line, exactly as the reader will read it
        try:
            text = _dumps(d)
        except (TypeError, ValueError, OverflowError, RecursionError) as e:
            raise _Bad(f"not storable as JSON ({e})") from None
        back = _check_pose(_loads(text))
    except _Bad as e:
        raise SessionError(f"{pre}: {e}") from None
    return text.encode("utf-8") + b"\n", back


def _header_line(header: Mapping[str, Any], where: str) -> bytes:
    """The exact bytes of the header line, validated as the reader will validate it."""
    try:
        h = dict(header)
        for k, v in h.items():  # field by field first, so that the message names the field
            if k == "truth" and isinstance(v, dict):
                _check_truth(v)  # NaN in a matrix: say which
            try:
                _dumps(v)
            except (TypeError, ValueError, OverflowError, RecursionError) as e:
                raise _Bad(f"field '{k}' is not storable as JSON ({e})") from None
        try:
            text = _dumps(h)
        except (TypeError, ValueError, OverflowError, RecursionError) as e:
            raise _Bad(f"not storable as JSON ({e})") from None
        _check_header(_loads(text))
    except _Bad as e:
        raise SessionError(f"{where}: {e}") from None
    return text.encode("utf-8") + b"\n"


# --- reading --------------------------------------------------------------------------------

@dataclass
class Session:
    """A session read from disk: ``header`` (dict), ``poses`` (list of PoseRecord, file order),
    ``path``, ``torn_tail`` (True when a torn last line was ignored), ``good_bytes`` (the
    length of the file without a torn last line, for resuming) and ``damaged``: the lines that
    were skipped as damaged, as (line number, reason), in file order."""

    header: dict[str, Any]
    poses: list[PoseRecord]
    path: Path | None = None
    torn_tail: bool = False
    good_bytes: int = 0
    damaged: list[tuple[int, str]] = field(default_factory=list)

    @property
    def bodies(self) -> list[str]:
        """Tracked body names from the header, e.g. ["marker", "probe"]."""
        return list(self.header.get("bodies", []))

    @property
    def truth(self) -> dict[str, np.ndarray] | None:
        """Ground truth {"X", "Z"[, "Y"]} (4×4 mm) when the session was simulated, else None.
        Raises SessionError if the header's truth is malformed."""
        t = self.header.get("truth")
        if not t:
            return None
        try:
            return _check_truth(t)
        except _Bad as e:
            raise SessionError(f"{self.path or 'session'}: header: {e}") from None

    def indices(self) -> set[int]:
        """Pose indices recorded so far (skipped poses included)."""
        return {p.index for p in self.poses}

    def damage_summary(self, limit: int = 5) -> str | None:
        """One line for the user about the damaged lines skipped, or None when there were none,
        e.g. "2 damaged lines skipped: line 12 (not valid JSON …), line 40 (field 'A': …)"."""
        if not self.damaged:
            return None
        n = len(self.damaged)
        parts = [f"line {no} ({why})" for no, why in self.damaged[:limit]]
        more = f", and {n - limit} more" if n > limit else ""
        return (f"{n} damaged line{'s' if n != 1 else ''} skipped: " + ", ".join(parts) + more)

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
    _header_line(h, "session header")
    return h


def _open_regular(p: Path, flags: int, what: str) -> int:
    """os.open for a regular file only: a FIFO, device or directory is refused without
    blocking (checked before opening, opened non-blocking, and checked again after)."""
    try:
        st = os.stat(p)
    except FileNotFoundError:
        st = None
    except OSError as e:
        raise SessionError(f"{p}: cannot {what} ({e.strerror or e})") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
        raise SessionError(f"{p}: {kind}; a session is a regular file")
    try:
        fd = os.open(p, flags | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0), 0o644)
    except FileExistsError:
        raise SessionError(f"{p}: already exists; refusing to overwrite "
                           "(choose another name, or resume it)") from None
    except OSError as e:
        if e.errno == errno.ENXIO:
            raise SessionError(f"{p}: not a regular file; a session is a regular file") \
                from None
        raise SessionError(f"{p}: cannot {what} ({e.strerror or e})") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise SessionError(f"{p}: not a regular file; a session is a regular file")
    return fd


def _read_all(fd: int) -> bytes:
    chunks = []
    pos = 0
    while True:
        b = os.pread(fd, 1 << 20, pos)
        if not b:
            return b"".join(chunks)
        chunks.append(b)
        pos += len(b)


def read_session(path: str | os.PathLike[str], *, strict: bool = False) -> Session:
    """Read and validate a session file (only a regular file; a FIFO is refused at once).

    A torn last line (no newline, not valid JSON) is ignored with a warning. A damaged line
    in the middle (not valid JSON, JSON that fails validation, or a pose index already read)
    is skipped with a warning naming the file, the line and the reason, and listed in
    ``Session.damaged``; the poses on either side are kept. With ``strict=True`` the first
    damaged line raises SessionError instead. A damaged header (line 1), an empty or
    unreadable file always raise SessionError naming the file and the line."""
    p = Path(path)
    fd = _open_regular(p, os.O_RDONLY, "read session file")
    try:
        data = _read_all(fd)
    except OSError as e:
        raise SessionError(f"{p}: cannot read session file ({e.strerror or e})") from None
    finally:
        os.close(fd)
    return _parse(data, p, strict)


def _parse(data: bytes, p: Path, strict: bool) -> Session:
    if not data.strip():
        raise SessionError(f"{p}: empty file, not a tmscal session")
    lines = data.split(b"\n")
    ends_with_newline = data.endswith(b"\n")
    if ends_with_newline:
        lines = lines[:-1]
    header: dict[str, Any] | None = None
    poses: list[PoseRecord] = []
    damaged: list[tuple[int, str]] = []
    seen: dict[int, int] = {}
    torn = False
    offset = 0
    for no, raw in enumerate(lines, start=1):
        last = no == len(lines)
        line_len = len(raw) + (1 if (not last or ends_with_newline) else 0)
        try:
            try:
                text = raw.decode("utf-8-sig" if no == 1 else "utf-8")
            except UnicodeDecodeError as e:
                raise _Bad(f"not valid UTF-8 ({e.reason} at byte {e.start})") from None
            if "\x00" in text:
                raise _Bad("not valid JSON (holds a NUL byte)")
            obj = _loads(text, finite=header is None)
            if header is None:
                header = _check_header(obj)
            else:
                rec = _check_pose(obj)
                if rec.index in seen:
                    raise _Bad(f"pose index {rec.index} already on line {seen[rec.index]}")
                seen[rec.index] = no
                poses.append(rec)
        except _Bad as e:
            reason = str(e)
            if header is None:
                raise SessionError(f"{p}, line {no}: {reason}") from None
            if (last and not ends_with_newline and reason.startswith("not valid")):
                log.warning("%s, line %d: torn last line ignored (an interrupted write)", p, no)
                torn = True
                break
            if strict:
                raise SessionError(f"{p}, line {no}: {reason}") from None
            log.warning("%s, line %d: damaged line skipped: %s", p, no, reason)
            damaged.append((no, reason))
        offset += line_len
    if header is None:
        raise SessionError(f"{p}: no header line")
    return Session(header=header, poses=poses, path=p, torn_tail=torn, good_bytes=offset,
                   damaged=damaged)


# --- writing --------------------------------------------------------------------------------

def _lock(fd: int, p: Path) -> None:
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise SessionError(f"{p}: in use by another tmscal process (locked); wait for it to "
                           "finish or stop it, or write to another file") from None
    except OSError as e:
        os.close(fd)
        raise SessionError(f"{p}: cannot lock the session file ({e.strerror or e})") from None


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


def _fsync_dir(p: Path) -> None:
    try:
        dfd = os.open(p.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)


class SessionWriter:
    """Append-only session writer: each pose is one line, written with O_APPEND and fsynced.

    ``SessionWriter.create(path, header)`` starts a new file (refuses to overwrite an
    existing one unless ``overwrite``); ``SessionWriter.resume(path)`` reopens an existing
    session for appending, cutting off a torn last line first and keeping damaged lines as
    they are. Both hold an exclusive advisory lock (``flock``) on the file until ``close``; a
    second writer on the same file, in this process or another, gets SessionError ("in use
    by another tmscal process (locked)"). Every line is validated as the reader will validate
    it before anything is written. Context manager."""

    def __init__(self, path: Path, fd: int, session: Session) -> None:
        self.path = path
        self._fd: int | None = fd
        self.session = session

    @classmethod
    def create(cls, path: str | os.PathLike[str], header: Mapping[str, Any],
               overwrite: bool = False) -> SessionWriter:
        """Start a new session file with ``header`` (validated as the reader will); fsynced.
        Without ``overwrite`` the file is created exclusively (O_EXCL): an existing file,
        even one created a moment ago by another process, is refused."""
        p = Path(path)
        line = _header_line(header, f"{p}: header")
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise SessionError(f"{p}: cannot write session file ({e.strerror or e})") from None
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | (0 if overwrite else os.O_EXCL)
        fd = _open_regular(p, flags, "write session file")
        _lock(fd, p)
        try:
            if overwrite:
                os.ftruncate(fd, 0)  # only now that the lock is ours
            _write_all(fd, line)
            os.fsync(fd)
        except OSError as e:
            os.close(fd)
            raise SessionError(f"{p}: cannot write session file ({e.strerror or e})") from None
        _fsync_dir(p)
        return cls(p, fd, Session(header=json.loads(line), poses=[], path=p,
                                  good_bytes=len(line)))

    @classmethod
    def resume(cls, path: str | os.PathLike[str]) -> SessionWriter:
        """Reopen an existing session for appending, under the lock: a torn last line is cut
        off; damaged lines in the middle stay in the file untouched (their poses count as not
        recorded, so they are acquired again and appended)."""
        p = Path(path)
        fd = _open_regular(p, os.O_RDWR | os.O_APPEND, "reopen session for appending")
        _lock(fd, p)
        try:
            data = _read_all(fd)  # read under the lock: no other writer can change it now
            s = _parse(data, p, strict=False)
            if s.torn_tail:
                os.ftruncate(fd, s.good_bytes)
                if os.fstat(fd).st_size != s.good_bytes:
                    raise SessionError(f"{p}: changed while cutting off its torn last line")
            if s.good_bytes > 0 and data[s.good_bytes - 1:s.good_bytes] != b"\n":
                _write_all(fd, b"\n")  # a complete last line without its newline
            os.fsync(fd)
        except SessionError:
            os.close(fd)
            raise
        except OSError as e:
            os.close(fd)
            raise SessionError(f"{p}: cannot reopen session for appending "
                               f"({e.strerror or e})") from None
        return cls(p, fd, s)

    def append(self, rec: PoseRecord) -> None:
        """Validate one pose (as the reader will), append its line and fsync it. Raises
        SessionError naming the pose and the field, writing nothing, if the reader would
        reject the line or the index is already recorded."""
        if self._fd is None:
            raise SessionError(f"{self.path}: the session writer is closed")
        line, back = _line_for(rec, str(self.path))
        if back.index in self.session.indices():
            raise SessionError(f"{self.path}: pose index {back.index} is already recorded")
        fd = self._fd
        try:
            size = os.fstat(fd).st_size
        except OSError as e:
            raise SessionError(f"{self.path}: cannot append pose {back.index} "
                               f"({e.strerror or e})") from None
        try:
            _write_all(fd, line)
            os.fsync(fd)
        except OSError as e:
            try:  # leave no partial line behind (we hold the lock, the size is ours)
                os.ftruncate(fd, size)
            except OSError:
                pass
            raise SessionError(f"{self.path}: cannot append pose {back.index} "
                               f"({e.strerror or e})") from None
        self.session.poses.append(back)
        self.session.good_bytes = size + len(line)

    def close(self) -> None:
        """Close the file and release the lock (safe twice)."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
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
