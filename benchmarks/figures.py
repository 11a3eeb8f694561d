"""The named figures a benchmark script prints, written for `benchmarks/check_figures.py`.

Every script that README.md or docs/ quote calls :func:`record` with the figures it has just
printed, {name: value}; they are merged into ``benchmarks/out/<script>.json`` (gitignored), so
runs with different options (``ml_bound.py --n 20`` and ``--n 250``) add their own names. The
value is the number as printed (the same rounding), its unit the one the printed line states.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

OUT = Path(__file__).resolve().parent / "out"


def record(script: str, figures: dict[str, float | int | None]) -> Path:
    """Merge `figures` into benchmarks/out/<script>.json (``TMSCAL_FIGURES_DIR`` overrides the
    folder) and return the file's path."""
    out = Path(os.environ.get("TMSCAL_FIGURES_DIR", OUT))
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{script}.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    old.update({k: (None if v is None else float(v)) for k, v in figures.items()})
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(old, indent=1, sort_keys=True) + "\n")
    tmp.replace(path)
    return path
