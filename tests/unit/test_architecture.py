"""The architecture of docs/architecture.md, file by file (``make lint`` checks the layers
between packages with import-linter; this checks what it does not): the FILE-level import
graph of tmscal/ (module- and function-level imports, ``TYPE_CHECKING`` ones too, relative
imports resolved) has no cycle; nothing outside tmscal/cli/ calls ``print``; calib/ imports
nothing that does I/O or knows a device. The checker itself is tried on small packages
written for it, so that each check is seen to fail."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

import tmscal

PACKAGE = Path(tmscal.__file__).resolve().parent

#: what calib/ may import from tmscal: itself and the ground below it (docs/architecture.md)
CALIB_MAY_IMPORT = ("tmscal.calib", "tmscal.errors", "tmscal.geometry", "tmscal.timing",
                    "tmscal.motion", "tmscal.poses")
#: outside modules whose only use is I/O with a device, a process or the network
IO_MODULES = ("socket", "serial", "subprocess")


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _files(root: Path) -> dict[str, Path]:
    """Module name → file, for every .py file of the package at ``root``."""
    return {_module_name(root, p): p for p in sorted(root.rglob("*.py"))}


def _imports(name: str, path: Path) -> Iterator[tuple[str, list[str] | None, int]]:
    """Every import statement of a file, at any depth of it: (absolute module, the names
    taken from it (None for ``import X``), line); relative imports resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, None, node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[:len(parts) - (node.level - 1)]
                base = ".".join(parts + ([node.module] if node.module else []))
            yield base, [a.name for a in node.names], node.lineno


def _targets(name: str, path: Path, files: dict[str, Path]) -> Iterator[tuple[str, int]]:
    """(module of the package, line) of every file the file imports: for ``from X import
    y`` the file X.y when y is a module of its own, else X (whose ``__init__`` defines y); a
    name the package has no file for stands for the nearest package that contains it."""
    for base, names, line in _imports(name, path):
        subs = [f"{base}.{n}" for n in names or () if f"{base}.{n}" in files]
        for s in subs:
            yield s, line
        if names is None or len(subs) < len(names):
            target = base
            while target and target not in files:
                target = target.rpartition(".")[0]
            if target:
                yield target, line


def import_graph(root: Path) -> dict[str, dict[str, int]]:
    """FILE-level import graph of the package at ``root``: module → {imported module of the
    package: first line}; imports of a file by itself left out."""
    files = _files(root)
    graph: dict[str, dict[str, int]] = {}
    for m, path in files.items():
        edges: dict[str, int] = {}
        for target, line in _targets(m, path, files):
            if target != m:
                edges.setdefault(target, line)
        graph[m] = edges
    return graph


def find_cycle(graph: dict[str, dict[str, int]]) -> list[str] | None:
    """One import cycle as the list of its modules (the first again at the end), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        path.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                return path[path.index(t):] + [t]
            if t not in state:
                found = visit(t)
                if found:
                    return found
        path.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def print_calls(root: Path, allowed: str) -> list[str]:
    """``file:line`` of every call of the builtin ``print`` outside the subpackage
    ``allowed`` (a folder name under ``root``)."""
    out = []
    for path in sorted(root.rglob("*.py")):
        if path.relative_to(root).parts[0] == allowed:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                    and node.func.id == "print":
                out.append(f"{path.relative_to(root.parent)}:{node.lineno}")
    return out


def io_imports(root: Path, sub: str, may_import: tuple[str, ...]) -> list[str]:
    """``file:line: module`` of every import in the subpackage ``sub`` of a module of the
    package outside ``may_import`` (the package's own ``__init__`` aside), or of one of
    ``IO_MODULES``."""
    files = _files(root)
    top = root.name
    out = []
    for path in sorted((root / sub).rglob("*.py")):
        name = _module_name(root, path)
        where = f"{path.relative_to(root.parent)}"
        for target, line in _targets(name, path, files):
            if target != top and not any(target == m or target.startswith(m + ".")
                                         for m in may_import):
                out.append(f"{where}:{line}: {target}")
        for base, _, line in _imports(name, path):
            if base.split(".")[0] in IO_MODULES:
                out.append(f"{where}:{line}: {base}")
    return sorted(set(out))


# --- the checks on tmscal -------------------------------------------------------------------

def test_no_import_cycle_between_files():
    graph = import_graph(PACKAGE)
    assert len(graph) > 100 and sum(len(t) for t in graph.values()) > 300  # the real tree
    cycle = find_cycle(graph)
    assert cycle is None, (
        "import cycle between files: " + " -> ".join(
            f"{a} (line {graph[a][b]})" for a, b in zip(cycle, cycle[1:], strict=False))
        + f" -> {cycle[-1]}; move the shared piece to the module it belongs in")


def test_only_the_cli_prints():
    found = print_calls(PACKAGE, "cli")
    assert not found, ("print() outside tmscal/cli/ (library code logs and raises; "
                       "docs/architecture.md): " + ", ".join(found))


def test_calib_imports_nothing_that_does_io():
    found = io_imports(PACKAGE, "calib", CALIB_MAY_IMPORT)
    assert not found, ("calib/ is pure numerics (no I/O, no devices; it may import "
                       f"{', '.join(CALIB_MAY_IMPORT)}): " + "; ".join(found))


# --- the checker, on packages written for it --------------------------------------------------

def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "pkg"
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text, encoding="utf-8")
    return root


def test_the_checker_finds_a_cycle_through_a_function_level_relative_import(tmp_path):
    root = _package(tmp_path, {
        "__init__.py": "",
        "low/__init__.py": "",
        "low/a.py": "def f():\n    from ..high import b\n    return b\n",
        "high/__init__.py": "",
        "high/b.py": "from ..low.a import f\n",
    })
    graph = import_graph(root)
    assert graph["pkg.high.b"] == {"pkg.low.a": 1}
    assert graph["pkg.low.a"] == {"pkg.high.b": 2}
    assert find_cycle(graph) == ["pkg.high.b", "pkg.low.a", "pkg.high.b"]


def test_the_checker_sees_a_cycle_through_a_package_init(tmp_path):
    """A package whose ``__init__`` imports a submodule that imports a name defined in the
    ``__init__`` is a cycle; a submodule imported as a module is not an edge to the
    ``__init__``."""
    init = _package(tmp_path, {
        "__init__.py": "from .a import f\nX = 1\n",
        "a.py": "from . import X\n\ndef f():\n    return X\n",
    })
    assert find_cycle(import_graph(init)) == ["pkg", "pkg.a", "pkg"]
    (init / "a.py").write_text("from . import b\n\ndef f():\n    return b.X\n")
    (init / "b.py").write_text("X = 1\n")
    (init / "__init__.py").write_text("from .a import f\n")
    graph = import_graph(init)
    assert graph["pkg.a"] == {"pkg.b": 1} and find_cycle(graph) is None


def test_the_checker_finds_prints_and_io_imports(tmp_path):
    root = _package(tmp_path, {
        "__init__.py": "",
        "cli/__init__.py": "print('ok here')\n",
        "calib/__init__.py": "from .. import errors\n",
        "calib/x.py": "import socket\n\ndef f():\n    print('no')\n"
                      "    from ..session import read\n    return read\n",
        "errors.py": "",
        "session.py": "def read():\n    pass\n",
    })
    assert print_calls(root, "cli") == ["pkg/calib/x.py:4"]
    found = io_imports(root, "calib", ("pkg.calib", "pkg.errors"))
    assert found == ["pkg/calib/x.py:1: socket", "pkg/calib/x.py:5: pkg.session"]


@pytest.mark.parametrize("sub", ["calib", "cli"])
def test_the_graph_has_the_subpackages_it_checks(sub):
    assert any(m.startswith(f"tmscal.{sub}.") for m in import_graph(PACKAGE))
