"""How big the two environments of the Makefile are: the one ``make demo`` builds (tmscal's
dependencies only, ``DEMO_EXTRAS``) and the one ``make test`` builds (``TEST_EXTRAS``: the test
tools, the third-party clients and simulators the tests run against, matplotlib, ur_rtde).

Each is built from nothing in a temporary folder exactly as the Makefile builds it (``python
-m venv``, pip upgraded, ``pip install -e '.[EXTRAS]'`` from this checkout; the extras are read
from the Makefile's ``DEMO_EXTRAS :=`` and ``TEST_EXTRAS :=`` lines), and measured: the
folder's size on disk (MB, 10⁶ bytes, as ``du`` counts allocated blocks), the distributions
installed, and the largest of them. pip's cache is used as pip uses it, so a second run
downloads nothing; the sizes do not depend on it. Takes minutes (the test environment is
large); needs PyPI or pip's cache. A benchmark, not a test: no test runs it.

    python benchmarks/install_size.py [--python python3] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from figures import record  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
MB = 1e6


def makefile_extras(makefile: Path = ROOT / "Makefile") -> dict[str, str]:
    """{"demo": DEMO_EXTRAS, "test": TEST_EXTRAS} as the Makefile sets them (an empty
    string: no extra). SystemExit naming the line when one is missing."""
    text = makefile.read_text(encoding="utf-8")
    out = {}
    for name in ("demo", "test"):
        m = re.search(rf"^{name.upper()}_EXTRAS\s*:=[ \t]*(\S*)[ \t]*$", text, re.M)
        if m is None:
            raise SystemExit(f"{makefile}: no '{name.upper()}_EXTRAS :=' line")
        out[name] = m.group(1)
    return out


def disk_bytes(path: Path) -> int:
    """Bytes allocated on disk under ``path`` (files and folders, symlinks not followed)."""
    total = 0
    for root, dirs, files in os.walk(path):
        for n in dirs + files:
            st = os.lstat(os.path.join(root, n))
            total += st.st_blocks * 512
    return total


def _dist_sizes(venv: Path) -> list[tuple[str, int]]:
    """(distribution name, bytes of the files its RECORD lists) of every installed
    distribution, largest first."""
    code = ("import importlib.metadata as m, json, os\n"
            "out = []\n"
            "for d in m.distributions():\n"
            "    n = 0\n"
            "    for f in d.files or []:\n"
            "        p = d.locate_file(f)\n"
            "        try:\n"
            "            n += os.lstat(p).st_blocks * 512\n"
            "        except OSError:\n"
            "            pass\n"
            "    out.append((d.metadata['Name'], n))\n"
            "print(json.dumps(out))\n")
    r = subprocess.run([str(venv / "bin" / "python"), "-c", code], check=True,
                       capture_output=True, text=True)
    return sorted(((str(n), int(b)) for n, b in json.loads(r.stdout)), key=lambda x: -x[1])


def build(python: str, venv: Path, extras: str) -> float:
    """Build ``venv`` as the Makefile does with ``extras``; returns the seconds it took."""
    t0 = time.perf_counter()
    py = str(venv / "bin" / "python")
    spec = "." + (f"[{extras}]" if extras else "")
    for cmd in ([python, "-m", "venv", str(venv)],
                [py, "-m", "pip", "install", "--quiet", "--upgrade", "pip"],
                [py, "-m", "pip", "install", "--quiet", "-e", spec]):
        subprocess.run(cmd, cwd=ROOT, check=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--python", default="python3", help="the Python that makes the venvs "
                    "(the Makefile's PYTHON; default python3)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="build the venvs in this folder and keep them (default: a temporary "
                         "folder, removed)")
    args = ap.parse_args()
    extras = makefile_extras()
    tmp = None
    if args.keep is None:
        tmp = tempfile.TemporaryDirectory(prefix="tmscal-install-size-")
        base = Path(tmp.name)
    else:
        base = args.keep
        base.mkdir(parents=True, exist_ok=True)
    figures: dict[str, float] = {}
    try:
        for name in ("demo", "test"):
            venv = base / f"venv-{name}"
            secs = build(args.python, venv, extras[name])
            total = disk_bytes(venv)
            dists = _dist_sizes(venv)
            spec = "-e ." + (f"[{extras[name]}]" if extras[name] else "")
            print(f"make {name}: pip install {spec}: {total / MB:.0f} MB on disk, "
                  f"{len(dists)} distributions, built in {secs:.0f} s")
            print("  largest: " + ", ".join(f"{n} {b / MB:.0f} MB" for n, b in dists[:6]))
            figures[f"{name}_mb"] = round(total / MB)
            figures[f"{name}_dists"] = len(dists)
        print(f"the demo's environment is {figures['demo_mb'] / figures['test_mb'] * 100:.0f} % "
              "of the test one's")
    finally:
        if tmp is not None:
            tmp.cleanup()
    record("install_size", figures)


if __name__ == "__main__":
    main()
