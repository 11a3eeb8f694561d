"""CI builds the wheel and runs the demo and the rig acceptance checks from it on the fast
clock.

The wheel is built from a copy of the sources (``pip wheel --no-deps``, with build isolation as
a user's pip would), installed as a lab installs it, ``pip install tmscal`` with no extra, into
a fresh venv (``python -m venv``; the dependencies, ur_rtde among them, come from PyPI or pip's
cache), and ``tmscal demo`` runs from a temp folder, so the source tree is not importable and
the demo's config and tool ROMs must come from the package data (``tmscal/data/configs/``):
the installed demo config, its mock addresses made the test's own
(``tests.rigs.unique_addresses``: the packaged UR address, 127.0.0.2, may be in use by another
test run), its ROM paths pointing into the installed package. Then ``tmscal selftest --rig``
runs the acceptance checks (``tests/acceptance`` is not in the wheel) on that mock rig and
writes its report. SLOW: about a minute (building, installing numpy/scipy/ur_rtde from the
cache, 20 poses through the wire protocols); it needs PyPI or a warm pip cache.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from ..rigs import REPO, unique_addresses

pytestmark = [pytest.mark.e2e, pytest.mark.wheel, pytest.mark.timeout(600)]

STEP_GUARD_S = 400.0   # hang guard per step (a cold pip cache downloads ~100 MB)


def _run(cmd: list[str], cwd: Path, env: dict[str, str]) -> str:
    try:
        r = subprocess.run(cmd, cwd=cwd, env=env, text=True, capture_output=True,
                           stdin=subprocess.DEVNULL, timeout=STEP_GUARD_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"hung for {STEP_GUARD_S:g} s: {' '.join(cmd)}")
    assert r.returncode == 0, f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stderr[-3000:]}"
    return r.stdout


def _clean_env() -> dict[str, str]:
    """The environment without this venv or the source tree on any path."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME", "PYTHONSTARTUP")}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    return env


def _build_wheel(tmp_path: Path, env: dict[str, str]) -> Path:
    """The wheel, built from a copy of what setuptools reads (no in-tree build/ left behind)."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, src / name)
    shutil.copytree(REPO / "tmscal", src / "tmscal",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    dist = tmp_path / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(dist),
          str(src)], tmp_path, env)
    (wheel,) = dist.glob("tmscal-*.whl")
    return wheel


def test_wheel_installs_and_runs_the_demo(tmp_path):
    env = _clean_env()
    wheel = _build_wheel(tmp_path, env)
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], tmp_path, env)
    py, tmscal = venv / "bin" / "python", venv / "bin" / "tmscal"
    _run([str(py), "-m", "pip", "install", "--quiet", str(wheel)], tmp_path, env)
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    where = _run([str(py), "-c", "import tmscal; print(tmscal.__file__)"], cwd, env)
    assert Path(where.strip()).is_relative_to(venv), f"tmscal imported from {where}"
    data = Path(_run([str(py), "-c", "import pathlib, tmscal.data; "
                      "print(pathlib.Path(tmscal.data.__file__).parent / 'configs')"],
                     cwd, env).strip())
    assert data.is_relative_to(venv), f"package data at {data}"
    cfg = unique_addresses(yaml.safe_load((data / "mock-ur-polaris.yaml").read_text()))
    cfg["tracker"]["tools"] = {k: str(data / v) for k, v in cfg["tracker"]["tools"].items()}
    (cwd / "demo.yaml").write_text(yaml.safe_dump(cfg))
    out = _run([str(tmscal), "demo", "--config", "demo.yaml", "--poses", "20", "--samples", "5",
                "--json"], cwd, env)
    result = json.loads(out)
    assert result["n_skipped"] == 0
    assert result["truth"]["coil_placement_mm"] < 0.3
    # the acceptance checks from the installed package, on the same mock rig
    r = subprocess.run([str(tmscal), "selftest", "--rig", "demo.yaml", "--report", "rig.txt"],
                       cwd=cwd, env=env, text=True, capture_output=True,
                       stdin=subprocess.DEVNULL, timeout=STEP_GUARD_S)
    assert r.returncode == 0, r.stdout + r.stderr
    text = (cwd / "rig.txt").read_text()
    assert "result: PASS (4 passed, 0 failed, 1 skipped)" in text, text
    for line in ("[PASS] connect and identity", "[PASS] small move inside the envelope and back",
                 "[SKIP] stop while moving", "driver: ur", "driver: ndi"):
        assert line in text, (line, text)
