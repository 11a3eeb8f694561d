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

from .files import Session, SessionWriter, read_session, sha256_of, write_session
from .jsonable import json_default, json_safe, plain
from .records import (
    FORMAT,
    VERSION,
    PoseRecord,
    make_header,
    records_from_arrays,
    seen_counts,
    seen_text,
    skip_cause,
    validate_record,
)

__all__ = ["FORMAT", "VERSION", "PoseRecord", "Session", "SessionWriter", "make_header",
           "read_session", "records_from_arrays", "sha256_of", "validate_record",
           "write_session", "skip_cause", "seen_counts", "seen_text", "plain", "json_safe",
           "json_default"]
