"""The README's tour, run from the README text itself so the README cannot drift.

The commands are the indented blocks of the section "A tour of the commands" (fenced blocks,
such as the Python example, are not commands). They run in order through bash in a temp folder
that holds the shipped configs under ``configs/``, as in the clone's root where the README says
to run them, with the test's environment on PATH (as after ``. .venv/bin/activate``):

* ``CMD &`` starts CMD in the background (``tmscal mock``), as an interactive shell would;
* ``kill $!`` stops that background command (SIGTERM, as ``kill`` sends) and expects exit 0;
* every other line runs to completion and must exit 0 (the README's own ``until grep -q
  serving mock.log`` line is the wait for the mock; the test adds only a hang guard).

The mock configs are copies whose every mock address is a loopback address of the test's own
(``tests.rigs.unique_addresses``; ports kept): the shipped 127.0.0.2 and :8765 may be in use by
another test, another test run or a ``tmscal mock`` left running. Nothing else in them changes
but their comments (the copies are written back from the parsed YAML).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from ..rigs import CONFIGS, REPO, unique_addresses

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(1800)]

README = REPO / "README.md"
SECTION = "## A tour of the commands"
# per command, only against a hang: the whole tour takes ~30 s on 2 idle cores, and a command
# (the adaptive acquire) has taken over 120 s on a loaded 2-core machine
HANG_GUARD_S = 600.0
_COMMENT = re.compile(r"\s+#\s.*$")


def tour_commands(readme: str) -> list[str]:
    """The shell commands of the README's tour: the lines of its indented code blocks outside
    ``` fences, trailing ``# comments`` removed."""
    start = readme.index(SECTION)
    end = readme.find("\n## ", start + len(SECTION))
    lines = readme[start:end if end >= 0 else None].splitlines()
    commands, fenced, prev_blank = [], False, True
    in_block = False
    for line in lines:
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("    ") and line.strip() and (prev_blank or in_block):
            commands.append(_COMMENT.sub("", line.strip()))
            in_block = True
        elif line.strip():
            in_block = False
        prev_blank = not line.strip()
    return commands


def tour_folder(tmp_path: Path) -> Path:
    """A folder with ``configs/`` (copies of the shipped configs, every mock address the
    test's own)."""
    configs = tmp_path / "configs"
    shutil.copytree(CONFIGS, configs)
    for path in configs.glob("mock-*.yaml"):
        path.write_text(yaml.safe_dump(unique_addresses(yaml.safe_load(path.read_text())),
                                       sort_keys=False))
    return tmp_path


def _stop(proc: subprocess.Popen) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    return proc.returncode


def run_tour(commands: list[str], cwd: Path) -> dict[str, str]:
    """Run the commands in order as described in the module docstring; returns each
    foreground command's stdout. AssertionError naming the command when one fails."""
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    background: list[subprocess.Popen] = []
    outputs: dict[str, str] = {}
    try:
        for cmd in commands:
            if cmd.endswith("&"):
                background.append(subprocess.Popen(
                    ["bash", "-c", "exec " + cmd[:-1].strip()], cwd=cwd, env=env,
                    stdin=subprocess.DEVNULL))
            elif cmd == "kill $!":
                assert background, "`kill $!` with no background command"
                rc = _stop(background.pop())
                assert rc == 0, f"the background command ended with exit code {rc}"
            else:
                try:
                    r = subprocess.run(["bash", "-c", cmd], cwd=cwd, env=env, text=True,
                                       stdin=subprocess.DEVNULL, capture_output=True,
                                       timeout=HANG_GUARD_S)
                except subprocess.TimeoutExpired:
                    pytest.fail(f"README command hung for {HANG_GUARD_S:g} s: {cmd}")
                assert r.returncode == 0, (f"README command failed (exit {r.returncode}): "
                                           f"{cmd}\n{r.stderr[-2000:]}")
                outputs[cmd] = r.stdout
        assert not background, "the tour leaves a background command running"
    finally:
        for proc in background:
            _stop(proc)
    return outputs


def test_readme_tour_parses_to_every_command():
    """The parser finds the tour: every rig and offline command, a background mock and its
    stop (so a README edit that hides commands from the test fails here)."""
    commands = tour_commands(README.read_text(encoding="utf-8"))
    used = {c.split()[1] for c in commands if c.startswith("tmscal ")}
    assert used >= {"simulate", "solve", "study", "mock", "track", "robot", "acquire", "demo",
                    "compare", "export", "stream", "report", "selfcal"}
    assert any(c.startswith("tmscal mock") and c.endswith("&") for c in commands)
    assert "kill $!" in commands


def test_readme_tour_runs_as_written(tmp_path):
    """Every tour command of the README, pasted in order, works; the DENSO demo at the end
    recovers the mock rig's truth (coil placement within 0.3 mm)."""
    commands = tour_commands(README.read_text(encoding="utf-8"))
    outputs = run_tour(commands, tour_folder(tmp_path))
    # every file it wrote is in out/ (.gitignore covers it), nothing beside the configs
    assert sorted(p.name for p in tmp_path.iterdir()) == ["configs", "out"]
    demo = [out for cmd, out in outputs.items() if cmd.startswith("tmscal demo")]
    assert demo, "the tour has no `tmscal demo` command"
    result = json.loads(demo[-1])
    assert result["truth"]["coil_placement_mm"] < 0.3
