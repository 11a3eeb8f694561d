"""Issue 22's mutation check, in the suite: a fixed few of ``benchmarks/mutation.py``'s mutants
of the motion-safety code (the envelope check, the split route through P0, the tool-point
speed law, the chord-sag margin) and of the audit's other breaks (the report's HTML escape, a
speed in m/s accepted), each applied to a copy of the package in the test's tmp dir,
and the tests the script names for it must FAIL there. The working tree is never edited (an
interrupted run leaves it as it was). The copy first passes those tests unmutated, so a failure
under a mutant is the mutant's doing.

Only the unit tests named for a mutant run here (its e2e ones are left to the script: ``python
benchmarks/mutation.py`` runs every mutant against every test named for it).
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path
from types import ModuleType

import pytest

from ..rigs import REPO

#: the mutants run here: the box's walls, the split route, the speed law, the sag margin, the
#: report's escape, a speed in m/s
CHOSEN = ("box-wall-sign", "split-condition", "speed-times-r", "sag-margin", "html-escape",
          "units-speed")


def _mutation() -> ModuleType:
    """``benchmarks/mutation.py`` (a script, not a package), loaded by path."""
    spec = importlib.util.spec_from_file_location("tmscal_bench_mutation",
                                                  REPO / "benchmarks" / "mutation.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module   # dataclasses look their module up while being defined
    spec.loader.exec_module(module)
    return module


mutation = _mutation()
MUTANTS = {m.name: m for m in mutation.MUTANTS}


def unit_tests(m) -> tuple[str, ...]:
    """The unit tests the script names for mutant ``m``."""
    return tuple(t for t in m.tests if t.startswith("tests/unit/"))


def failed(out: str) -> set[str]:
    """The node ids pytest's ``-rf`` summary lists as FAILED."""
    return set(re.findall(r"^FAILED (\S+?)(?: - .*)?$", out, re.M))


def test_the_chosen_mutants_exist_and_name_unit_tests() -> None:
    for name in CHOSEN:
        assert name in MUTANTS, f"benchmarks/mutation.py has no mutant {name!r}"
        assert unit_tests(MUTANTS[name]), f"mutant {name!r} names no unit test"


def test_the_unmutated_copy_passes_the_named_tests(tmp_path: Path) -> None:
    copy = mutation.copy_tree(tmp_path / "copy")
    assert mutation.imports_the_copy(copy), "the copy's tmscal is not the one imported"
    tests = tuple(dict.fromkeys(t for n in CHOSEN for t in unit_tests(MUTANTS[n])))
    r = mutation.pytest_in(copy, tests, "-rf")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert re.search(rf"^{len(tests)} passed", r.stdout, re.M), r.stdout[-2000:]


@pytest.mark.parametrize("name", CHOSEN)
def test_the_mutant_is_killed_by_its_tests(tmp_path: Path, name: str) -> None:
    m = MUTANTS[name]
    before = (REPO / m.path).read_bytes()
    copy = mutation.copy_tree(tmp_path / "copy")
    assert mutation.apply(m, copy), f"{name}: the text to replace is not once in {m.path}"
    assert (copy / m.path).read_bytes() != before
    assert (REPO / m.path).read_bytes() == before     # the working tree is untouched
    assert mutation.imports_the_copy(copy), "the copy's tmscal is not the one imported"
    tests = unit_tests(m)
    r = mutation.pytest_in(copy, tests, "-rf")
    # exit 1: tests ran and failed (not 2-4: interrupted, internal or usage error)
    assert r.returncode == 1, f"{name} SURVIVED ({m.what}):\n{r.stdout[-3000:]}{r.stderr[-2000:]}"
    assert failed(r.stdout) == set(tests), r.stdout[-3000:]


@pytest.mark.parametrize("name", list(MUTANTS))
def test_every_mutant_still_applies_to_the_code(name: str) -> None:
    """A change to the guarded code must not quietly disable a mutant of the script: the text
    it replaces is in its file exactly once."""
    m = MUTANTS[name]
    assert (REPO / m.path).read_text().count(m.old) == 1, \
        f"benchmarks/mutation.py: mutant {name!r} no longer applies to {m.path}"
