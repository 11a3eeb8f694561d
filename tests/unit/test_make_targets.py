"""The Makefile's two entry points (README.md, first lines): ``make demo`` builds an
environment of its own with tmscal's dependencies only (``DEMO_EXTRAS`` empty: no test
tools), ``make test`` the test environment with ``TEST_EXTRAS`` (test, plot, ur) and runs the
linters and the suite; ``.ci/run`` runs exactly the README's test command.

Nothing is installed: the recipes are read from GNU make's own dry runs (``make -n -B``, which
prints every command of a target without running one) and its variable database (``make
-p``), in an environment without the variables a surrounding ``make test`` passes down.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="GNU make is not installed")

#: variables a surrounding make (``make test PYTEST_ARGS=…``) or the shell could hand down
_MAKE_ENV = ("MAKEFLAGS", "MFLAGS", "MAKELEVEL", "MAKEOVERRIDES", "PYTHON", "PYTEST_ARGS",
             "PYTEST_WORKERS", "DEMO_EXTRAS", "TEST_EXTRAS", "VENV", "DEMO_VENV")


def _make(*args: str) -> str:
    env = {k: v for k, v in os.environ.items() if k not in _MAKE_ENV}
    r = subprocess.run(["make", *args], cwd=REPO, env=env, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    return r.stdout


def _dry_run(target: str) -> list[str]:
    """Every command ``make TARGET`` would run from nothing (``-B``: as if no environment
    were built yet), in order."""
    return [ln for ln in _make("-n", "-B", target).splitlines() if ln.strip()]


def _variables() -> dict[str, str]:
    """The Makefile's simply expanded variables as make evaluates them (``make -p``)."""
    out = {}
    for m in re.finditer(r"^([A-Z_]+) := ?(.*)$", _make("-p", "-n", "-B", "demo"), re.M):
        out.setdefault(m.group(1), m.group(2).strip())
    return out


def _installs(lines: list[str]) -> list[tuple[str, str]]:
    """(the venv's python, the spec) of every ``pip install -e SPEC`` line."""
    out = []
    for ln in lines:
        m = re.match(r"(\S+)/bin/python -m pip install .*-e '([^']*)'", ln)
        if m:
            out.append((m.group(1), m.group(2)))
    return out


def _readme_commands() -> list[str]:
    """The commands of the README's first code block (indented lines), comments left out."""
    block: list[str] = []
    for ln in (REPO / "README.md").read_text(encoding="utf-8").splitlines()[1:]:
        if ln.startswith("    ") and ln.strip():
            block.append(ln.split("#", 1)[0].strip())
        elif block and ln.strip():
            break
    return block


def _readme_comment(command: str) -> str:
    for ln in (REPO / "README.md").read_text(encoding="utf-8").splitlines():
        if ln.startswith("    ") and ln.split("#", 1)[0].strip() == command:
            return ln.split("#", 1)[1]
    raise AssertionError(f"{command!r} not in README.md")


def _names(requirements: list[str]) -> set[str]:
    return {re.split(r"[\s<>=!~;\[]", r, maxsplit=1)[0].lower().replace("_", "-")
            for r in requirements}


def test_the_extras_of_each_environment() -> None:
    v = _variables()
    assert v["DEMO_EXTRAS"] == ""
    assert v["TEST_EXTRAS"].split(",") == ["test", "plot", "ur"]
    assert v["DEMO_VENV"] != v["VENV"]
    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]
    assert set(v["TEST_EXTRAS"].split(",")) <= set(extras)  # pip would warn, not fail


def test_install_size_reads_the_extras_make_uses() -> None:
    """benchmarks/install_size.py measures the environments make builds."""
    spec = importlib.util.spec_from_file_location("install_size",
                                                  REPO / "benchmarks" / "install_size.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    v = _variables()
    assert mod.makefile_extras(REPO / "Makefile") == {"demo": v["DEMO_EXTRAS"],
                                                      "test": v["TEST_EXTRAS"]}


def test_make_demo_builds_its_own_environment_without_the_test_extra() -> None:
    v = _variables()
    lines = _dry_run("demo")
    assert lines[0].split()[-3:] == ["-m", "venv", v["DEMO_VENV"]]
    assert _installs(lines) == [(v["DEMO_VENV"], ".")]  # tmscal alone, no extra
    assert not [ln for ln in lines if f"{v['VENV']}/" in ln.replace(v["DEMO_VENV"], "")]
    assert lines[-1] == f"{v['DEMO_VENV']}/bin/tmscal demo"
    # and tmscal's own dependencies bring no test tool
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    tools = {"pytest", "pytest-xdist", "hypothesis", "ruff", "import-linter"}
    assert tools <= _names(project["optional-dependencies"]["test"])
    assert not tools & _names(project["dependencies"])


def test_make_test_builds_the_test_environment_and_runs_lint_and_the_suite() -> None:
    v = _variables()
    lines = _dry_run("test")
    assert lines[0].split()[-3:] == ["-m", "venv", v["VENV"]]
    assert _installs(lines) == [(v["VENV"], f".[{v['TEST_EXTRAS']}]")]
    assert not [ln for ln in lines if v["DEMO_VENV"] in ln]
    ruff = next(i for i, ln in enumerate(lines) if f"{v['VENV']}/bin/ruff check" in ln)
    pytest_at = next(i for i, ln in enumerate(lines) if f"{v['VENV']}/bin/python -m pytest" in ln)
    assert ruff < pytest_at == len(lines) - 1


def test_the_readme_names_each_environment() -> None:
    v = _variables()
    assert v["DEMO_VENV"] in _readme_comment("make demo")
    assert f"{v['VENV']} " in _readme_comment("make test") + " "


def test_ci_runs_exactly_the_readmes_test_command() -> None:
    """Of the README's first commands, the one whose recipe runs the suite is what .ci/run
    runs, as written and last (its status is the job's)."""
    commands = _readme_commands()
    assert commands, "README.md has no code block at its top"
    runs_suite = [c for c in commands if c.startswith("make ")
                  and any(" -m pytest" in ln for ln in _dry_run(c.split(None, 1)[1]))]
    assert len(runs_suite) == 1, commands
    script = (REPO / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    code = [ln.strip() for ln in script if ln.strip() and not ln.strip().startswith("#")]
    assert "set -euo pipefail" in code
    makes = [ln for ln in code if re.search(r"(^|[;&|\s])make\b", ln)]
    assert makes == runs_suite
    assert code[-1] == runs_suite[0]
