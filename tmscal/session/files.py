"""Session files on disk: ``read_session`` (salvaging damaged middle lines), the locked,
append-only ``SessionWriter``, ``write_session`` and ``sha256_of``. Line formats and their
validation are in ``tmscal.session.records``.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import logging
import os
import stat
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SessionError
from ..filekind import wrong_kind
from .checks import BadLine
from .outputs import fsync_dir, install, new_temp
from .records import (
    PoseRecord,
    header_line,
    parse_json,
    record_line,
    validate_header,
    validate_pose,
)
from .truth import validate_truth, validate_truth_arm

log = logging.getLogger(__name__)

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
            return validate_truth(t)
        except BadLine as e:
            raise SessionError(f"{self.path or 'session'}: header: {e}") from None

    @property
    def truth_arm(self) -> dict[str, Any] | None:
        """The simulated rig's arm (the header's ``truth.arm``; docs/session-format.md), or
        None when the session has none: {"name": the registry name, "errors": the protocol
        of its hidden errors, "nominal": the controller's model and "true": the arm's
        (:class:`~tmscal.calib.kinematics.Arm`, mm and rad, in the robot's base frame),
        "mount": 4×4 mm rig frame ← robot base}: the rig-frame flange at joints q is
        mount · forward(arm, q), the reported A with the nominal arm, the one the tracker
        sees (B = Z⁻¹ · it · X) with the true. Raises SessionError naming the key if it is
        malformed."""
        t = self.header.get("truth")
        if not isinstance(t, dict) or "arm" not in t:
            return None
        try:
            return validate_truth_arm(t["arm"])
        except BadLine as e:
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
        # every pose in ``use`` has A and B (and C when has_c): the filters drop nothing, they
        # only tell the type checker so
        A = np.stack([p.A for p in use if p.A is not None])
        B = np.stack([p.B for p in use if p.B is not None])
        has_c = all(p.C is not None for p in use)
        C = np.stack([p.C for p in use if p.C is not None]) if has_c else None
        return A, B, C, [p.index for p in use]

    def joints(self, indices: list[int], missing: str = "the robot's driver did not report "
               "them when it was recorded") -> np.ndarray:
        """The recorded joint angles (m, n) rad of the poses ``indices`` (e.g. from
        ``arrays``), in that order. Raises SessionError naming the first pose that has none
        (then ``missing``: why it matters or how it came about), or whose joint count differs
        from the first pose's."""
        by_index = {p.index: p for p in self.poses}
        rows: list[list[float]] = []
        where = self.path or "session"
        for i in indices:
            q = by_index[i].joints_rad if i in by_index else None
            if q is None:
                raise SessionError(f"{where}: pose {i} has no joint angles ('joints_rad'); "
                                   + missing)
            if rows and len(q) != len(rows[0]):
                raise SessionError(f"{where}: pose {i} has {len(q)} joint angles, pose "
                                   f"{indices[0]} has {len(rows[0])}")
            rows.append(list(q))
        return np.array(rows, dtype=np.float64).reshape(len(rows), -1)

    def wrenches(self, indices: list[int]) -> tuple[np.ndarray, np.ndarray] | None:
        """(W (m, 6), σ (m, 6)) of the poses ``indices`` when every one recorded a wrench:
        the averaged [Fx, Fy, Fz N, Tx, Ty, Tz N·m] in the sensor frame and the σ of that
        mean, its spread / √samples (NaN where a pose recorded no spread); else None."""
        by_index = {p.index: p for p in self.poses}
        use = [by_index[i] for i in indices if i in by_index]
        if not use or len(use) != len(indices) or any(p.wrench is None for p in use):
            return None
        W = np.array([p.wrench for p in use], dtype=np.float64)
        sem = np.full((len(use), 6), np.nan)
        for k, p in enumerate(use):
            if p.wrench_spread is not None:
                n = max(int(p.samples.get("wrench", 1)), 1)
                sem[k] = np.asarray(p.wrench_spread, dtype=np.float64) / np.sqrt(n)
        return W, sem


def _open_regular(p: Path, flags: int, what: str) -> int:
    """os.open of an existing regular file only (reading, resuming; new files are made by
    ``outputs.new_temp``): a FIFO, device or directory is refused without blocking (checked
    before opening, opened non-blocking, and checked again after)."""
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
        fd = os.open(p, flags | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
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
    chunks: list[bytes] = []
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
                raise BadLine(f"not valid UTF-8 ({e.reason} at byte {e.start})") from None
            if "\x00" in text:
                raise BadLine("not valid JSON (holds a NUL byte)")
            obj = parse_json(text, finite=header is None)
            if header is None:
                header = validate_header(obj)
            else:
                rec = validate_pose(obj)
                if rec.index in seen:
                    raise BadLine(f"pose index {rec.index} already on line {seen[rec.index]}")
                seen[rec.index] = no
                poses.append(rec)
        except BadLine as e:
            reason = str(e)
            if header is None:
                other = wrong_kind(str(p), data[:65536].decode("utf-8", "replace"), "session")
                raise SessionError(other or f"{p}, line {no}: {reason}") from None
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


def _unlink_quietly(p: Path) -> None:
    try:
        os.unlink(p)
    except OSError:
        pass


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


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

        The header is written whole or not at all: to a new file beside ``path`` (mode
        0666 & ~umask), locked, fsynced, and only then given the name ``path``
        (``tmscal.session.outputs.install``); a failure (a full disk) leaves nothing at
        ``path``. Without ``overwrite`` an existing file, even one created a moment ago by
        another process, is refused; with it the existing file is replaced only if no other
        tmscal process holds it locked."""
        p = Path(path)
        line = header_line(header, f"{p}: header")
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise SessionError(f"{p}: cannot write session file ({e.strerror or e})") from None
        try:
            st = os.stat(p)
        except OSError:
            st = None
        if st is not None:
            if not stat.S_ISREG(st.st_mode):
                kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
                raise SessionError(f"{p}: {kind}; a session is a regular file")
            if not overwrite:
                raise SessionError(f"{p}: already exists; refusing to overwrite it "
                                   "(choose another name, or resume it)")
        fd, tmp = new_temp(p, os.O_WRONLY | os.O_APPEND)
        try:
            _lock(fd, p)  # before the file has its name: it is never seen unlocked
        except SessionError:
            _unlink_quietly(tmp)
            raise
        try:
            _write_all(fd, line)
            os.fsync(fd)
            install(tmp, p, overwrite, hint="choose another name, or resume it")
        except (OSError, SessionError) as e:
            os.close(fd)
            _unlink_quietly(tmp)
            if isinstance(e, SessionError):
                raise
            raise SessionError(f"{p}: cannot write session file ({e.strerror or e})") from None
        fsync_dir(p)
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
        line, back = record_line(rec, str(self.path))
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


