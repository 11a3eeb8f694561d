"""What every tmscal file reader shares (the calibration file, :mod:`.calibfile`; the
kinematics file, :mod:`.kinfile`): reading a bounded UTF-8 text file, parsing it as YAML or
JSON, and checking a 4×4 matrix (mm), each problem one ``CalibrationError`` naming the file
and the dotted key."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import CalibrationError
from ..filekind import read_kind
from ..geometry import RIGID_TOL_DEFAULT, check_pose

__all__ = ["MAX_BYTES", "RAW_LIMIT", "bad", "check_matrix", "load_text", "read_text_file"]

#: the largest file a reader takes
MAX_BYTES = 4_000_000
#: the solver's general (raw) matrices may be affine; this bounds them to something a
#: calibration can be (|entries of the 3×3 block| ≤ 10, a non-singular block)
RAW_LIMIT = 10.0


def bad(src: str, key: str, msg: str) -> CalibrationError:
    """One error naming the file and the dotted key."""
    return CalibrationError(f"{src}: key '{key}': {msg}")


def check_matrix(v: Any, src: str, key: str, rigid: bool) -> np.ndarray:
    """A 4×4 matrix (mm) from nested lists: finite numbers, last row 0 0 0 1; ``rigid``: an
    orthonormal rotation (det +1); otherwise a non-singular, bounded 3×3 block."""
    if not isinstance(v, list) or len(v) != 4 or not all(
            isinstance(r, list) and len(r) == 4 for r in v):
        raise bad(src, key, "expected a 4×4 matrix (four rows of four numbers)")
    for i, r in enumerate(v):
        for j, x in enumerate(r):
            if isinstance(x, bool) or not isinstance(x, int | float):
                raise bad(src, f"{key}[{i}][{j}]", f"{x!r:.40} is not a number")
            if not math.isfinite(x):
                raise bad(src, f"{key}[{i}][{j}]", f"{x!r} is not a finite number")
    M = np.array(v, dtype=float)
    try:
        check_pose(M, "matrix", rigid=rigid, tol=RIGID_TOL_DEFAULT)
    except ValueError as e:
        raise bad(src, key, str(e).removeprefix("matrix: ").replace("pose 0 ", "")) from None
    if not rigid:
        R = M[:3, :3]
        if np.abs(R).max() > RAW_LIMIT or abs(np.linalg.det(R)) < 1e-6:
            raise bad(src, key, "the 3×3 block is singular or implausibly large for a "
                      "calibration")
    return M


def load_text(text: str, src: str) -> Any:
    """The document of a YAML or JSON file (JSON when it starts with '{')."""
    if text.lstrip().startswith("{"):
        def no_constant(c: str) -> None:
            raise ValueError(f"{c} is not a finite number")
        try:
            return json.loads(text, parse_constant=no_constant)
        except (ValueError, RecursionError) as e:
            raise CalibrationError(f"{src}: invalid JSON ({str(e)[:120]})") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise CalibrationError(f"{src}{where}: invalid YAML "
                               f"({getattr(e, 'problem', None) or e})") from None
    except RecursionError:
        raise CalibrationError(f"{src}: invalid YAML (nested too deeply)") from None
    except (ValueError, OverflowError, TypeError) as e:
        raise CalibrationError(f"{src}: invalid YAML ({str(e)[:120]})") from None


def read_text_file(p: Path, what: str, kind: str) -> str:
    """The UTF-8 text of regular file ``p`` of at most ``MAX_BYTES``, a tmscal file of
    ``kind`` (``what`` it is called in messages, e.g. "calibration file"); CalibrationError
    naming the file otherwise, saying what the file is when it is of another kind of tmscal
    file (``tmscal.filekind.read_kind``: a session given as a calibration, …)."""
    return read_kind(p, kind, what, MAX_BYTES, CalibrationError)
