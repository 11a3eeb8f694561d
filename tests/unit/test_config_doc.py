"""Every driver option is declared once (issue 29, item 4): the settings class's ``OPTIONS``
hold type, range, default, unit and help; the driver's constructor takes its defaults from
them and checks its arguments against the same ranges; and docs/configs.md's option tables
are what ``tmscal.config.doc`` renders from them."""

from __future__ import annotations

import inspect
import math
from pathlib import Path
from typing import Any

import pytest

from tmscal import registry
from tmscal.config import settings_class
from tmscal.config.doc import main, marker, option_default, option_type, options_table, render
from tmscal.config.settings import Option

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "configs.md"
DECLARED = [(s.kind, s.name) for s in registry.BUILTIN
            if settings_class(s.kind, s.name).OPTIONS]
IDS = [marker(k, n) for k, n in DECLARED]
#: the required arguments of each built-in driver (by its docs marker), to build one
#: (nothing is opened)
REQUIRED: dict[str, dict[str, Any]] = {
    "ur": {"host": "192.0.2.1"}, "denso": {}, "franka": {"host": "192.0.2.1"},
    "ndi": {"port": "/dev/ttyUSB0", "tools": {"marker": None}},
    "igtl": {"host": "192.0.2.1", "tools": {"marker": "MarkerToTracker"}},
    "ati": {"host": "192.0.2.1", "counts_per_force": 1e6, "counts_per_torque": 1e6},
    "ur_wrench": {"host": "192.0.2.1"},
    "sim/robot": {}, "sim/tracker": {"tools": {"marker": "marker"}},
}


def test_docs_configs_tables_are_the_declarations() -> None:
    text = DOC.read_text(encoding="utf-8")
    assert render(text) == text, ("docs/configs.md: the option tables differ from the "
                                  "drivers' OPTIONS; run python -m tmscal.config.doc")


@pytest.mark.parametrize("kind, name", DECLARED, ids=IDS)
def test_every_driver_with_options_has_a_generated_table(kind: str, name: str) -> None:
    text = DOC.read_text(encoding="utf-8")
    m = marker(kind, name)
    assert f"<!-- options: {m} " in text and f"<!-- /options: {m} -->" in text


def test_a_name_of_two_kinds_is_marked_with_its_kind() -> None:
    """``sim`` is a robot and a tracker: each table is its own kind's declaration."""
    assert (marker("robot", "sim"), marker("tracker", "sim"), marker("robot", "ur")) == \
        ("sim/robot", "sim/tracker", "ur")
    robot = render("<!-- options: sim/robot x -->\n<!-- /options: sim/robot -->")
    tracker = render("<!-- options: sim/tracker x -->\n<!-- /options: sim/tracker -->")
    assert "`fail_after_moves`" in robot and "`fail_after_moves`" not in tracker
    assert "`drop_tool`" in tracker and "`drop_tool`" not in robot
    with pytest.raises(ValueError, match="no built-in driver 'sim'"):
        render("<!-- options: sim x -->\n<!-- /options: sim -->")


def test_render_replaces_a_stale_table_and_keeps_the_rest(tmp_path: Path) -> None:
    stale = ("before\n<!-- options: franka (generated) -->\n| option |\n| `old` |\n"
             "<!-- /options: franka -->\nafter `x`\n")
    out = render(stale)
    assert out.startswith("before\n<!-- options: franka (generated) -->\n| option | type |")
    assert out.endswith("<!-- /options: franka -->\nafter `x`\n")
    assert "`old`" not in out and "| `auto_recover` | true or false | — | false |" in out
    assert render(out) == out
    p = tmp_path / "configs.md"
    p.write_text(stale, encoding="utf-8")
    with pytest.raises(SystemExit, match="differ from the drivers' declarations"):
        main(["--check", str(p)])
    assert p.read_text(encoding="utf-8") == stale     # --check writes nothing
    assert main([str(p)]) == 0 and p.read_text(encoding="utf-8") == out
    assert main(["--check", str(p)]) == 0


def test_an_unknown_driver_marker_is_refused() -> None:
    with pytest.raises(ValueError, match="no built-in driver 'kuka'"):
        render("<!-- options: kuka x -->\n<!-- /options: kuka -->")


def test_the_columns() -> None:
    assert option_type(Option(int, lo=1, hi=65535)) == "int 1…65535"
    assert option_type(Option(float, lo=0.01, hi=100)) == "number in 0.01…100"
    assert option_type(Option(float, above=0, hi=500, null=True)) == \
        "number > 0 and ≤ 500, or null"
    assert option_type(Option(bool, null=True)) == "true, false or null"
    assert option_type(Option(str, choices=("raw", "tcp"))) == "`raw` or `tcp`"
    assert [option_default(Option(t, default=d)) for t, d in
            [(bool, True), (float, 30.0), (str, "Arm"), (int, None)]] == \
        ["true", "30", "`Arm`", "null"]
    table = options_table({"a": Option(float, above=0, default=2.0, unit="s", help="wait")})
    assert table.splitlines()[2] == "| `a` | number > 0 | s | 2 | wait |"


@pytest.mark.parametrize("kind, name", DECLARED, ids=IDS)
def test_every_option_is_a_constructor_argument_with_the_declared_default(kind: str,
                                                                        name: str) -> None:
    declared = settings_class(kind, name).OPTIONS or {}
    params = inspect.signature(registry.get_spec(name, kind).load()).parameters
    for k, o in declared.items():
        assert k in params, f"{name}: option {k!r} is no argument of the driver"
        assert params[k].default == o.default, k
        assert o.help, f"{name}: option {k!r} has no help for the docs"
        assert o.check(o.default, "src", k) == o.default, k   # the default is in range
        assert registry.get_spec(name, kind).load()(**REQUIRED[marker(kind, name)])  # defaults


def _outside(o: Option) -> list[Any]:
    """Values just outside ``o``'s range, and of the wrong type."""
    bad: list[Any] = ["x"] if o.type is not str else [5]
    if o.type in (int, float):
        step = 1 if o.type is int else 1e-6
        bad += [v - step for v in (o.lo,) if v is not None]
        bad += [v + step for v in (o.hi,) if v is not None]
        bad += [v for v in (o.above, o.below) if v is not None]
        if o.type is float:
            bad.append(math.nan)
    if not o.null:
        bad.append(None)
    return bad


@pytest.mark.parametrize("kind, name", DECLARED, ids=IDS)
def test_the_constructor_checks_the_declared_ranges(kind: str, name: str) -> None:
    """The driver refuses what the declaration refuses, naming the option, and takes the
    declaration's bounds themselves: its range is the declared one, not a copy."""
    declared = settings_class(kind, name).OPTIONS or {}
    cls = registry.get_spec(name, kind).load()
    required = REQUIRED[marker(kind, name)]
    for k, o in declared.items():
        for v in _outside(o):
            with pytest.raises(ValueError, match=rf"{cls.__name__}: {k}: expected"):
                cls(**required, **{k: v})
        for v in (o.lo, o.hi):
            if v is not None:
                assert getattr(cls(**required, **{k: v}), k, v) == v
