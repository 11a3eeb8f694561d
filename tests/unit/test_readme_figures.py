"""The benchmark figures of docs/benchmarks.md and README.md (its summary) and the other docs
name the command that prints them, and
benchmarks/check_figures.py reads their markers and fails when one is altered (no benchmark
is run: the check's input is written here from the text itself)."""

from __future__ import annotations

import importlib.util
import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
BENCHMARKS = ROOT / "docs" / "benchmarks.md"
COMMAND = re.compile(r"python benchmarks/\w+\.py|tmscal \w+|make test|bash \.ci/run|pytest")
# a measured number: digits with a unit or a ratio after them
MEASURE = re.compile(r"\d(?:<!--[^>]*-->)?\s?(?:mm|ms|s\b|%|×|°|min\b|frames/s)")


def _load():
    spec = importlib.util.spec_from_file_location("check_figures",
                                                  ROOT / "benchmarks" / "check_figures.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["check_figures"] = mod
    spec.loader.exec_module(mod)
    return mod


cf = _load()


def _benchmarks_section() -> list[str]:
    """docs/benchmarks.md whole, then the README's summary of it."""
    text = README.read_text(encoding="utf-8")
    start = text.index("\n## Benchmarks")
    end = text.index("\n## ", start + 1)
    return [*BENCHMARKS.read_text(encoding="utf-8").split("\n"), "",
            *text[start:end].split("\n")]


def _paragraphs(lines: list[str]) -> list[tuple[int, str]]:
    """(first line index, text) of each figure-bearing block with its command context."""
    out = []
    for i, line in enumerate(lines):
        if line.strip() and (i == 0 or not lines[i - 1].strip()):
            out.append((i, cf._paragraph(lines, i)))
    return out


def test_every_figure_paragraph_of_benchmarks_names_its_command():
    lines = _benchmarks_section()
    missing = [f"line {i}: {p[:80]!r}" for i, p in _paragraphs(lines)
               if not p.startswith("## ") and MEASURE.search(p) and not COMMAND.search(p)]
    assert not missing, "figures with no command in their paragraph:\n" + "\n".join(missing)


def test_every_marked_figure_sits_in_its_scripts_paragraph():
    figures = [f for p in cf.default_files() for f in cf.parse(p)]
    scripts = {f.script for f in figures}
    assert {"accuracy", "speed", "ml_selection", "adaptive_coverage", "kinematics",
            "selfcal", "methods", "ml_bound", "tracker", "acquisition", "time_to_calibrate",
            "selfcal_rig", "franka_demo"} <= scripts
    wrong = [f"{f.file}:{f.line} {f.name}" for f in figures
             if f"benchmarks/{f.script}.py" not in f.paragraph
             or not (ROOT / "benchmarks" / f"{f.script}.py").exists()]
    assert not wrong
    names = [f.name for f in figures]
    dup = {n for n in names if names.count(n) > 1}
    # a figure quoted twice must be quoted with the same number
    for n in dup:
        assert len({f.value for f in figures if f.name == n}) == 1, n


def test_every_marked_script_records_its_figures():
    """A script whose figures are marked writes them (benchmarks/figures.py's record with its
    own name), so that check_figures.py has an output to compare."""
    scripts = {f.script for p in cf.default_files() for f in cf.parse(p)}
    silent = [s for s in sorted(scripts)
              if f'record("{s}"' not in (ROOT / "benchmarks" / f"{s}.py").read_text()]
    assert not silent, f"marked but never recorded: {silent}"


def _outputs_from_text(figures, out: Path) -> None:
    data: dict[str, dict[str, float]] = {}
    for f in figures:
        data.setdefault(f.script, {})[f.key] = f.value
    out.mkdir()
    for script, d in data.items():
        (out / f"{script}.json").write_text(json.dumps(d))


def test_the_benchmark_tables_live_in_docs_and_the_readme_quotes_them():
    """README.md keeps a few headline figures, each the same as docs/benchmarks.md's (the
    check reads both: benchmarks/check_figures.py's default files)."""
    assert BENCHMARKS in cf.default_files() and README in cf.default_files()
    doc = {f.name: f.value for f in cf.parse(BENCHMARKS)}
    readme = [f for f in cf.parse(README) if f.script != "reregister_rig"]
    assert 3 <= len(readme) < 20 < len(doc)
    assert {f.name: f.value for f in readme}.items() <= doc.items()
    assert "| QR36 e_t min |" not in README.read_text(encoding="utf-8")


def test_check_passes_on_the_benchmarks_as_written_and_fails_on_an_altered_copy(tmp_path,
                                                                               capsys):
    figures = cf.parse(BENCHMARKS, "docs/benchmarks.md")
    assert len(figures) > 50
    out = tmp_path / "out"
    _outputs_from_text(figures, out)
    assert cf.main([str(BENCHMARKS), "--out", str(out)]) == 0
    text = BENCHMARKS.read_text(encoding="utf-8")
    old = "0.0744<!--fig ml_selection.ml_mm_n7 =-->"
    assert old in text
    altered = tmp_path / "benchmarks.md"
    altered.write_text(text.replace(old, old.replace("0.0744", "0.0751")), encoding="utf-8")
    capsys.readouterr()
    assert cf.main([str(altered), "--out", str(out)]) == 1
    printed = capsys.readouterr().out
    assert "ml_selection.ml_mm_n7: text 0.0751, output 0.0744, tolerance =" in printed


def test_a_figure_missing_from_the_output_is_named(tmp_path, capsys):
    md = tmp_path / "x.md"
    md.write_text("`python benchmarks/speed.py`: QR36 0.74<!--fig speed.qr36_ms_n20 ×3--> ms\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "speed.json").write_text(json.dumps({"qr36_ms_n20": 3.0}))
    assert cf.main([str(md), "--out", str(out)]) == 1
    assert "text 0.74, output 3, tolerance ×3" in capsys.readouterr().out
    (out / "speed.json").write_text(json.dumps({}))
    assert cf.main([str(md), "--out", str(out)]) == 1
    assert "not in speed.json" in capsys.readouterr().out


def test_a_figure_without_its_command_fails(tmp_path, capsys):
    md = tmp_path / "x.md"
    md.write_text("QR36 takes 0.74<!--fig speed.qr36_ms_n20 ×3--> ms\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "speed.json").write_text(json.dumps({"qr36_ms_n20": 0.74}))
    assert cf.main([str(md), "--out", str(out)]) == 1
    assert "does not name benchmarks/speed.py" in capsys.readouterr().out


@pytest.mark.parametrize(("text", "digits", "output", "tol", "ok"), [
    (0.184, "0.184", 0.18449, "=", True),
    (0.184, "0.184", 0.18451, "=", False),
    (40, "40", 39, "=", False),
    (34.8, "34.8", 52.0, "±50%", True),
    (34.8, "34.8", 53.0, "±50%", False),
    (1.0, "1.0", 2.9, "×3", True),
    (1.0, "1.0", 0.3, "×3", False),
    (0.55, "0.55", 0.56, "±0.01", True),
])
def test_tolerances(text, digits, output, tol, ok):
    assert cf.within(text, digits, output, tol) is ok


def test_a_marker_with_no_number_is_an_error(tmp_path):
    md = tmp_path / "x.md"
    md.write_text("para\nnone <!--fig speed.x =-->\n")
    with pytest.raises(ValueError, match="x.md:2"):
        cf.parse(md)
