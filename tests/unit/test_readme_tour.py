"""The README's tour can be run again as it stands (issue 24, item 6): every file it writes is
in out/, which .gitignore covers, and every command that writes a file says --force (or
continues a session with --resume, or writes nothing with --dry-run). The tour itself runs in
tests/e2e/test_readme.py, which also checks that it leaves nothing outside out/."""

from __future__ import annotations

import re
import shlex

from tests.e2e.test_readme import README, tour_commands
from tests.rigs import REPO

WRITES = ("-o", "--output", "--plot")


def _commands() -> list[str]:
    return tour_commands(README.read_text(encoding="utf-8"))


def test_the_tour_makes_out_first_and_gitignore_covers_it():
    cmds = _commands()
    assert cmds[0].startswith("mkdir -p out")
    ignored = (REPO / ".gitignore").read_text().split()
    assert "/out/" in ignored or "out/" in ignored


def test_every_file_the_tour_writes_is_in_out_and_every_writer_says_force():
    checked = 0
    for cmd in _commands():
        words = shlex.split(cmd.rstrip("&").strip())
        for redirect in re.findall(r">\s*(\S+)", cmd):
            assert redirect.startswith("out/"), cmd
        if not words or words[0] != "tmscal":
            continue
        outs = [words[i + 1] for i, w in enumerate(words[:-1]) if w in WRITES]
        for out in outs:
            assert out.startswith("out/"), f"writes outside out/: {cmd}"
        if outs:
            checked += 1
            assert {"--force", "--resume", "--dry-run"} & set(words), \
                f"writes a file without --force: {cmd}"
    assert checked >= 10  # the parser found the writers (the tour has 14)
