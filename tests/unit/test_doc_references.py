"""Every place and command the documentation names exists (issue 29, item 5).

Read: README.md, docs/*.md, the comments of pyproject.toml and the Makefile, and, in tmscal/,
every docstring, every click ``help=`` text and every comment. Checked:

- a dotted name ``tmscal.x.y`` imports as a module, or its longest importable prefix has the
  rest as attributes (``tmscal.exports.load_calibration``);
- a path (``tmscal/drivers/base.py``, ``docs/safety.md``, ``benchmarks/speed.py``,
  ``configs/ur-polaris.yaml``, a folder ``tmscal/mocks/``) exists relative to the repository's
  root, to tmscal/ (``calib/qr.py``, as the package's own texts write it) or to the file that
  names it; a Markdown link ``[..](x.md)`` exists relative to its file;
- a command ``tmscal COMMAND [SUBCOMMAND] --flag …`` written in backticks or in a code block
  is a command of the click tree ``tmscal.cli.main`` (a group's first word a subcommand), and
  each of its ``--flags`` (and ``-o``-style short options) is an option of that command.

The checker itself is run on small texts with a bad reference of each kind, so a check that
silently found nothing fails too.
"""

from __future__ import annotations

import ast
import importlib
import io
import re
import tokenize
from dataclasses import dataclass
from pathlib import Path

import click
import pytest

from tmscal.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "tmscal"

DOTTED = re.compile(r"(?<![\w./-])tmscal(?:\.[A-Za-z_]\w*)+")
#: a Sphinx role naming a module relative to the text's package (``:mod:`.adaptive```)
ROLE = re.compile(r":(?:mod|func|class|meth|data|attr|exc):`~?(\.+[A-Za-z_][\w.]*)`")
# a path with a folder part and a known suffix, or a folder of the repository ending in "/"
PATH = re.compile(r"(?<![\w./<{*$-])((?:[A-Za-z_][\w.-]*/)+[\w.-]*"
                  r"\.(?:py|md|yaml|yml|toml|rom|json|txt)"
                  r"|(?:tmscal|tests|benchmarks|docs|configs)/(?:[A-Za-z_]\w*/)*)(?![\w/<{*-])")
MDLINK = re.compile(r"\]\(([^)#\s]+\.md)(?:#[^)]*)?\)")
BACKTICK = re.compile(r"`+([^`]+?)`+")
#: roots a relative path may be written from: the clone, the package (``calib/qr.py``) and
#: the configs folder (docs/configs.md's ``tools/README.md``). A path whose first folder is
#: in none of them, nor beside the file naming it, is another project's (DENSO's
#: ``SimpleSamples/04_00_Move.py``) and is not checked.
ROOTS = (ROOT, PKG, ROOT / "configs")
#: folders a run makes (not in the repository)
MADE = ("out/", "benchmarks/out/", ".venv", "build/")
#: the names the docs use for an example of what a lab adds (docs/devices.md, "Adding a
#: driver"; pyproject.toml's entry-point example): not meant to exist
EXAMPLES = ("tmscal.drivers.lab", "tmscal.mocks.lab")
#: a rig config a reader writes themself (``configs/my-rig.yaml``)
PLACEHOLDER = re.compile(r"(?:^|/)(?:my-[\w.-]*|[A-Z]+)(?:/|$)")


def _loggers() -> set[str]:
    """The logger names the package's code asks for (``getLogger("tmscal.devices.stderr")``):
    dotted like modules, but not modules."""
    out = set()
    for p in PKG.rglob("*.py"):
        out |= set(re.findall(r"getLogger\(\s*[\"'](tmscal[\w.]*)[\"']", p.read_text()))
    return out


LOGGERS = _loggers()


@dataclass(frozen=True)
class Ref:
    where: str     # file:line
    kind: str      # "module", "path", "link", "command"
    text: str
    base: Path     # the folder of the file that names it


# ---------------------------------------------------------------- the texts


def _md_texts(path: Path) -> list[tuple[int, str, bool]]:
    """(line, text, is_code) pieces of a Markdown file: each line of a fenced or indented code
    block on its own, the prose of each paragraph joined (a backtick span may break a line)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    out: list[tuple[int, str, bool]] = []
    fenced = False
    para: list[str] = []
    start = 0
    prev_blank = True

    def flush() -> None:
        if para:
            out.append((start, "\n".join(para), False))
            para.clear()

    for i, line in enumerate(lines, 1):
        if line.lstrip().startswith("```"):
            flush()
            fenced = not fenced
            prev_blank = False
            continue
        if fenced or (line.startswith("    ") and prev_blank and not para
                      and not line.lstrip().startswith(("-", "|"))):
            out.append((i, line, True))
            continue
        if not line.strip():
            flush()
            prev_blank = True
            continue
        if not para:
            start = i
        para.append(line)
        prev_blank = False
    flush()
    return out


def _comments(source: str) -> list[tuple[int, str]]:
    out = []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            out.append((tok.start[0], tok.string))
    return out


def _py_texts(path: Path) -> list[tuple[int, str]]:
    """(line, text) of a module's docstrings, click ``help=`` strings and comments."""
    source = path.read_text(encoding="utf-8")
    tree = ast.parse(source)
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            doc = ast.get_docstring(node, clean=False)
            if doc and node.body:
                out.append((node.body[0].lineno, doc))
        elif isinstance(node, ast.Call):
            for kw in node.keywords:
                if kw.arg == "help":
                    for sub in ast.walk(kw.value):
                        if isinstance(sub, ast.Constant) and isinstance(sub.value, str):
                            out.append((sub.lineno, sub.value))
    return out + _comments(source)


def _hash_comments(path: Path) -> list[tuple[int, str]]:
    return [(i, line[line.index("#"):]) for i, line in
            enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if "#" in line]


def refs_in_markdown(path: Path, label: str) -> list[Ref]:
    out: list[Ref] = []
    for line, text, code in _md_texts(path):
        where = f"{label}:{line}"
        out += _names(text, where, path.parent)
        out += [Ref(_at(where, text, m.start()), "link", m.group(1), path.parent)
                for m in MDLINK.finditer(text)]
        spans = [(0, text)] if code else [(m.start(), m.group(1))
                                          for m in BACKTICK.finditer(text)]
        out += [Ref(_at(where, text, pos), "command", c, path.parent) for pos, s in spans
                for c in _commands(s, code)]
    return out


def refs_in_text(text: str, where: str, base: Path, package: str = "") -> list[Ref]:
    """References in a docstring, help text or comment (``package``: the dotted package a
    relative ``:mod:`.name``` is read from); commands only in backticks."""
    out = _names(text, where, base)
    for m in ROLE.finditer(text):
        dots = len(m.group(1)) - len(m.group(1).lstrip("."))
        parts = package.split(".")[:len(package.split(".")) - dots + 1]
        out.append(Ref(_at(where, text, m.start()), "module",
                       ".".join([*parts, m.group(1)[dots:]]), base))
    out += [Ref(_at(where, text, m.start()), "command", c, base)
            for m in BACKTICK.finditer(text) for c in _commands(m.group(1))]
    return out


def _at(where: str, text: str, pos: int) -> str:
    """``where`` (file:line of the text's first line) moved to the line of ``text[pos]``."""
    label, line = where.rsplit(":", 1)
    return f"{label}:{int(line) + text.count(chr(10), 0, pos)}"


def _names(text: str, where: str, base: Path) -> list[Ref]:
    out = [Ref(_at(where, text, m.start()), "module", m.group(0).rstrip("."), base)
           for m in DOTTED.finditer(text)]
    out += [Ref(_at(where, text, m.start()), "path", m.group(1), base)
            for m in PATH.finditer(text)]
    return out


def _commands(span: str, code: bool = False) -> list[str]:
    """The ``tmscal …`` command a backtick span starts with, or each one a code line runs
    (at its start, or after ``&&``, ``;``, ``|`` or ``$(``), up to a pipe, redirection,
    ``&``, ``;`` or a comment."""
    if code:
        span = re.sub(r"(?:^|\s)#.*", "", span)
        starts = [m.end() for m in re.finditer(r"(?:^\s*|&&\s*|;\s*|\|\s*|\$\()(?=tmscal )",
                                               span)]
    else:
        span = " ".join(span.split())
        starts = [0] if span.startswith("tmscal ") else []
    span_ = span
    out = []
    for start in starts:
        rest = span_[start:] if code else span_
        rest = re.split(r"\s[|&;>]|\s\d?>|\)|\s\(", rest)[0]
        out.append(" ".join(rest.split()))
    return out


# ---------------------------------------------------------------- the checks


def _module_ok(name: str) -> bool:
    if name in LOGGERS or name.startswith(EXAMPLES):
        return True
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ModuleNotFoundError:
            continue
        for attr in parts[k:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def _path_ok(text: str, base: Path) -> bool:
    if text.startswith(MADE) or "/out/" in text or PLACEHOLDER.search(text):
        return True
    first = text.split("/")[0]
    roots = [r for r in (*ROOTS, base) if (r / first).is_dir()]
    return not roots or any((r / text).exists() for r in roots)


def _options(cmd: click.Command) -> set[str]:
    opts = {"--help"}
    for p in cmd.params:
        if isinstance(p, click.Option):
            opts |= set(p.opts) | set(p.secondary_opts)
    return opts


def _command_problem(text: str, group: click.Group = cli_main) -> str | None:
    words = text.split()[1:]
    if not words or not re.fullmatch(r"[a-z][a-z_-]*", words[0]):
        return None   # "tmscal COMMAND --help": a placeholder
    cmd: click.Command | None = group.commands.get(words[0])
    if cmd is None:
        return f"no command {words[0]!r}"
    rest = words[1:]
    if isinstance(cmd, click.Group):
        if not rest or rest[0].startswith("-"):
            return None
        sub = cmd.commands.get(rest[0])
        if sub is None:
            return f"no subcommand {words[0]} {rest[0]!r}"
        cmd, rest = sub, rest[1:]
    known = _options(cmd)
    for w in rest:
        flag = w.split("=", 1)[0].rstrip(",.:`'\"")
        if re.fullmatch(r"--[a-z][a-z0-9-]*|-[a-zA-Z]", flag) and flag not in known:
            return f"{cmd.name} has no option {flag}"
    return None


def problems(refs: list[Ref]) -> list[str]:
    out = []
    for r in refs:
        if r.kind == "module" and not _module_ok(r.text):
            out.append(f"{r.where}: {r.text} does not import")
        elif r.kind == "path" and not _path_ok(r.text, r.base):
            out.append(f"{r.where}: no file or folder {r.text}")
        elif r.kind == "link" and not (r.base / r.text).exists():
            out.append(f"{r.where}: link to a missing {r.text}")
        elif r.kind == "command":
            why = _command_problem(r.text)
            if why:
                out.append(f"{r.where}: `{r.text}`: {why}")
    return sorted(set(out))


def _label(p: Path) -> str:
    return str(p.relative_to(ROOT))


def doc_refs() -> list[Ref]:
    out: list[Ref] = []
    for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        out += refs_in_markdown(p, _label(p))
    for p in (ROOT / "pyproject.toml", ROOT / "Makefile"):
        out += [r for line, text in _hash_comments(p)
                for r in refs_in_text(text, f"{_label(p)}:{line}", ROOT)]
    return out


def package_refs() -> list[Ref]:
    out: list[Ref] = []
    for p in sorted(PKG.rglob("*.py")):
        package = ".".join(p.relative_to(ROOT).parent.parts)
        out += [r for line, text in _py_texts(p)
                for r in refs_in_text(text, f"{_label(p)}:{line}", p.parent, package)]
    return out


# ---------------------------------------------------------------- the tests


def test_every_reference_of_the_docs_exists():
    refs = doc_refs()
    kinds = {r.kind for r in refs}
    # the reader found each kind (the docs name each other as `docs/x.md`, not as links)
    assert {"module", "path", "command"} <= kinds, kinds
    bad = problems(refs)
    assert not bad, "broken references:\n" + "\n".join(bad)


def test_every_reference_of_the_package_texts_exists():
    refs = package_refs()
    assert {"module", "path", "command"} <= {r.kind for r in refs}
    bad = problems(refs)
    assert not bad, "broken references:\n" + "\n".join(bad)


BAD = """\
The plan lives in `tmscal.acquisition.nowhere` and `tmscal.geometry.no_such_function`;
see `tmscal/drivers/nothing.py`, `calib/missing.py`, [the guide](nothing.md) and
`tmscal plan out/s.jsonl`, `tmscal solve out/s.jsonl --no-such-flag`,
`tmscal selfcal frobnicate`.

    tmscal acquire configs/mock-ur-polaris.yaml --poses 20 --wrong   # a comment --ignored
"""

GOOD = """\
`tmscal.geometry`, `tmscal.exports.load_calibration`, `tmscal/drivers/base.py`,
`calib/qr.py`, `docs/safety.md`, [safety](docs/safety.md), `tmscal solve out/s.jsonl --calib
out/rig.yaml -o out/x.yaml --force`, `tmscal selfcal simulate --pool 2000 --no-compare`,
`tmscal COMMAND --help`.

    tmscal mock configs/mock-ur-polaris.yaml > out/mock.log &   # --not-a-flag
"""


def test_the_checker_finds_each_kind_of_broken_reference(tmp_path):
    bad = tmp_path / "bad.md"
    bad.write_text(BAD)
    found = problems(refs_in_markdown(bad, "bad.md"))
    text = "\n".join(found)
    for piece in ("tmscal.acquisition.nowhere", "tmscal.geometry.no_such_function",
                  "tmscal/drivers/nothing.py", "calib/missing.py", "nothing.md",
                  "no command 'plan'", "no option --no-such-flag",
                  "no subcommand selfcal 'frobnicate'", "no option --wrong"):
        assert piece in text, f"missed {piece!r} in:\n{text}"
    assert "--ignored" not in text
    assert len(found) == 9, text


def test_the_checker_passes_good_references(tmp_path):
    good = tmp_path / "docs"
    good.mkdir()
    (good / "good.md").write_text(GOOD)
    refs = refs_in_markdown(good / "good.md", "good.md")
    # links are relative to the file: docs/safety.md from docs/ is a broken one
    assert problems(refs) == ["good.md:2: link to a missing docs/safety.md"]
    assert {r.kind for r in refs} == {"module", "path", "link", "command"}


def test_the_checker_reads_docstrings_help_texts_and_comments(tmp_path):
    mod = tmp_path / "m.py"
    mod.write_text('"""Uses ``tmscal.nowhere``."""\n'
                   "import click\n"
                   "# see tmscal/nothing.py\n"
                   "@click.option('--x', help='like `tmscal plan`')\n"
                   "def f():\n"
                   '    """Run ``tmscal solve --nope``."""\n')
    found = problems([r for line, text in _py_texts(mod)
                      for r in refs_in_text(text, f"m.py:{line}", tmp_path)])
    assert len(found) == 4, found
    assert any("tmscal.nowhere" in f for f in found)
    assert any("tmscal/nothing.py" in f for f in found)
    assert any("'plan'" in f for f in found)
    assert any("--nope" in f for f in found)


@pytest.mark.parametrize("name", ["tmscal.geometry", "tmscal.calib.qr", "tmscal.cli.main"])
def test_real_names_resolve(name):
    assert _module_ok(name)
