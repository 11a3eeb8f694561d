"""docs/configs.md says it covers every key (issue 24, item 6): every key and option of every
registered driver's settings class (the registry's ``settings``, which the config parser reads
them by) is named in that driver's paragraph of docs/configs.md, and every shipped config
(configs/*.yaml) is listed in its table of shipped configs."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tmscal import registry
from tmscal.config import settings_class

REPO = Path(__file__).resolve().parents[2]
DOC = (REPO / "docs" / "configs.md").read_text(encoding="utf-8")
BUILTIN = [(s.kind, s.name) for s in registry.BUILTIN]


def driver_paragraph(doc: str, name: str, kind: str | None = None) -> str:
    """The text of docs/configs.md about driver ``name``: from its bold ``**`name`**`` (the
    first in the section ``## `kind```, when given: ``sim`` is a robot and a tracker) to the
    next driver's or the next section."""
    start = doc.index(f"**`{name}`**", doc.index(f"## `{kind}`") if kind else 0)
    nxt = re.compile(r"^\*\*`[\w-]+`\*\*|^## ", re.M).search(doc, start + 1)
    return doc[start:nxt.start() if nxt else None]


def settings_keys(kind: str, name: str) -> list[str]:
    cls = settings_class(kind, name)
    return [*cls.KEYS, *(cls.OPTIONS or {})]


def test_every_builtin_driver_has_keys_or_options_to_document():
    assert {n for _, n in BUILTIN} >= {"ur", "denso", "franka", "ndi", "igtl", "ati",
                                       "ur_wrench"}
    assert all(settings_keys(k, n) for k, n in BUILTIN)


@pytest.mark.parametrize("kind, name", BUILTIN, ids=[n for _, n in BUILTIN])
def test_every_settings_key_of_every_driver_is_in_docs_configs(kind, name):
    text = driver_paragraph(DOC, name, kind)
    missing = [k for k in settings_keys(kind, name) if f"`{k}`" not in text]
    assert not missing, f"docs/configs.md, driver {name!r}: no row or mention of {missing}"


def test_the_paragraph_finder_stops_at_the_next_driver():
    doc = "**`a`** owns `x`.\n\n**`b`** owns `y`.\n\n## next\n`z`"
    assert driver_paragraph(doc, "a") == "**`a`** owns `x`.\n\n"
    assert driver_paragraph(doc, "b") == "**`b`** owns `y`.\n\n"
    two = "## `robot`\n**`a`** `x`\n## `tracker`\n**`a`** `y`\n"
    assert driver_paragraph(two, "a", "tracker") == "**`a`** `y`\n"


def test_every_shipped_config_is_listed():
    start = DOC.index("## Where the shipped configs are")
    table = DOC[start:DOC.index("\n## ", start + 1)]
    listed = set(re.findall(r"`([\w.-]+\.yaml)`", table))
    shipped = {p.name for p in (REPO / "configs").glob("*.yaml")}
    assert shipped, "no shipped configs found"
    assert not shipped - listed, f"not listed in docs/configs.md: {sorted(shipped - listed)}"
