"""Check the figures docs/*.md and README.md quote against the benchmarks' last output.

Reruns nothing: it reads the JSON the benchmark scripts wrote (``benchmarks/out/<script>.json``,
see ``benchmarks/figures.py``) and every figure marked in README.md and docs/*.md (the tables
are in docs/benchmarks.md, the README quotes a few), and exits 1,
naming each figure, the text's value, the output's value and the tolerance, when they differ by
more than the tolerance (or the output lacks the figure). ``make bench`` runs it last.

A figure is marked by an HTML comment right after its number (invisible when rendered)::

    QR36 e_t min 0.184<!--fig accuracy.qr36_e_t_min_median =--> mm

``accuracy`` names the script (and its JSON), ``qr36_e_t_min_median`` the figure. Tolerances:
``=`` exact to the printed digits (half a unit of the text's last digit), ``±0.01`` absolute,
``±50%`` relative, ``×10`` within a factor (order of magnitude). The paragraph holding the
figure (or, for a table or code block, the paragraph before it) must name the command that
prints it: ``benchmarks/<script>.py``.

    python benchmarks/check_figures.py [--only speed,ml_selection] [--out DIR] [FILES...]
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MARK = re.compile(r"<!--\s*fig\s+([A-Za-z0-9_]+)\.([A-Za-z0-9_.]+)\s+(\S+)\s*-->")
NUMBER = re.compile(r"[-−]?\d[\d,]*(?:\.\d+)?")


@dataclass(frozen=True)
class Figure:
    """One marked figure: where it is, its name, the number the text prints, its tolerance."""

    file: str
    line: int
    script: str
    key: str
    text: str          # the number as written
    tolerance: str
    paragraph: str     # the paragraph that must name the command

    @property
    def name(self) -> str:
        return f"{self.script}.{self.key}"

    @property
    def value(self) -> float:
        return float(self.text.replace(",", "").replace("−", "-"))


def _paragraph(lines: list[str], i: int) -> str:
    """The block around line i; a table's or code block's is extended by the paragraph above."""
    lo = i
    while lo > 0 and lines[lo - 1].strip():
        lo -= 1
    hi = i
    while hi + 1 < len(lines) and lines[hi + 1].strip():
        hi += 1
    block = lines[lo:hi + 1]
    if block and (block[0].lstrip().startswith("|") or block[0].startswith("    ")):
        j = lo - 1
        while j >= 0 and not lines[j].strip():
            j -= 1
        k = j
        while k > 0 and lines[k - 1].strip():
            k -= 1
        block = lines[k:j + 1] + block if j >= 0 else block
    return "\n".join(block)


def parse(path: Path, label: str | None = None) -> list[Figure]:
    """Every marked figure of a Markdown file. A marker with no number before it on its line
    raises ValueError naming the file and line."""
    lines = path.read_text(encoding="utf-8").splitlines()
    out: list[Figure] = []
    for i, line in enumerate(lines):
        for m in MARK.finditer(line):
            before = MARK.sub("", line[:m.start()])
            nums = NUMBER.findall(before)
            if not nums:
                raise ValueError(f"{label or path}:{i + 1}: figure {m.group(1)}.{m.group(2)} "
                                 "has no number before its marker")
            out.append(Figure(label or str(path), i + 1, m.group(1), m.group(2), nums[-1],
                              m.group(3), _paragraph(lines, i)))
    return out


def within(text: float, digits: str, output: float, tolerance: str) -> bool:
    """Whether the output's value agrees with the text's under the tolerance (see module)."""
    if tolerance == "=":
        frac = digits.split(".")[1] if "." in digits else ""
        half = 0.5 * 10.0 ** -len(frac)
        return abs(output - text) <= half * (1 + 1e-9) + 1e-12
    if tolerance.startswith("±") and tolerance.endswith("%"):
        return abs(output - text) <= abs(text) * float(tolerance[1:-1]) / 100
    if tolerance.startswith("±"):
        return abs(output - text) <= float(tolerance[1:]) * (1 + 1e-9)
    if tolerance.startswith(("×", "x")):
        f = float(tolerance[1:])
        return text > 0 and output > 0 and 1 / f <= output / text <= f
    raise ValueError(f"unknown tolerance {tolerance!r} (=, ±0.01, ±50%, ×10)")


def check(figures: list[Figure], out_dir: Path, only: set[str] | None = None) -> list[str]:
    """The failures, one line each; empty when every figure agrees."""
    problems: list[str] = []
    cache: dict[str, dict | None] = {}
    for f in figures:
        if only is not None and f.script not in only:
            continue
        where = f"{f.file}:{f.line} {f.name}"
        if f"benchmarks/{f.script}.py" not in f.paragraph:
            problems.append(f"{where}: its paragraph does not name benchmarks/{f.script}.py")
        if f.script not in cache:
            p = out_dir / f"{f.script}.json"
            cache[f.script] = json.loads(p.read_text()) if p.exists() else None
        data = cache[f.script]
        if data is None:
            problems.append(f"{where}: no output {out_dir / (f.script + '.json')} "
                            f"(run python benchmarks/{f.script}.py)")
            continue
        if f.key not in data or data[f.key] is None:
            problems.append(f"{where}: not in {f.script}.json's output")
            continue
        got = float(data[f.key])
        if math.isnan(got) or not within(f.value, f.text, got, f.tolerance):
            problems.append(f"{where}: text {f.text}, output {got:.6g}, tolerance {f.tolerance}")
    return problems


def default_files() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out")
    ap.add_argument("--only", help="comma-separated scripts to check (default: all)")
    a = ap.parse_args(argv)
    figures: list[Figure] = []
    for p in a.files or default_files():
        try:
            label = str(p.resolve().relative_to(ROOT))
        except ValueError:
            label = str(p)
        figures += parse(p, label)
    only = set(a.only.split(",")) if a.only else None
    problems = check(figures, a.out, only)
    n = sum(only is None or f.script in only for f in figures)
    for line in problems:
        print(line)
    print(f"{n} figures checked, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
