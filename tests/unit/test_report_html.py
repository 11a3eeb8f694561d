"""The HTML report (``tmscal report``, ``tmscal.report.html``) on small simulated sessions:
its sections, a page with nothing external, everything from the session escaped, the skipped
and the corrupted poses named, a stored calibration labelled held out or in-sample, and the
command's output-file rule."""

from __future__ import annotations

import base64
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.session import make_header, read_session, records_from_arrays, write_session
from tmscal.sim import Noise, simulate

pytest.importorskip("matplotlib")

#: the section ids docs/report.md lists, in page order
SECTION_IDS = ["verdict", "rig", "plan", "samples", "calibration", "errors", "convergence",
               "residuals"]

HOSTILE = '<script>alert("x")</script>&amp;'
REASON = '<img src=x onerror=alert(1)> probe usable in 3 of 100 frames'
SKIPPED, CORRUPTED = 7, 23  # pose indices


class _Page(HTMLParser):
    """Tags, attributes and text of a page."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data: str) -> None:
        self.text.append(data)


def _parse(page: str) -> _Page:
    p = _Page()
    p.feed(page)
    return p


def _session(path: Path, seed: int, n: int = 48) -> Path:
    """A simulated session of ``n`` poses with a hostile config name and device identity,
    sample spreads, pose SKIPPED skipped (REASON) and pose CORRUPTED's marker moved 5 mm."""
    truth, d = simulate(n, np.random.default_rng(seed), noise=Noise())
    header = make_header(["marker", "probe"], truth=truth.as_dict(),
                         config={"name": HOSTILE},
                         devices={"tracker": {"driver": "ndi", "serial": HOSTILE}})
    recs = records_from_arrays(d["A"], d["marker"], d["probe"], d["commanded"])
    rng = np.random.default_rng(seed + 1)
    for r in recs:
        r.spread = {b: {"trans_mm": float(rng.uniform(0.02, 0.05)),
                        "rot_deg": float(rng.uniform(0.01, 0.03))} for b in ("marker", "probe")}
    recs[SKIPPED].B = recs[SKIPPED].C = None
    recs[SKIPPED].skipped = REASON
    recs[CORRUPTED].B = recs[CORRUPTED].B.copy()
    recs[CORRUPTED].B[:3, 3] += [5.0, 0.0, 0.0]
    return write_session(path, header, recs)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("report")
    return _session(d / "a.jsonl", 11), _session(d / "b.jsonl", 12)


@pytest.fixture(scope="module")
def page(sessions, tmp_path_factory) -> str:
    out = tmp_path_factory.mktemp("page") / "r.html"
    r = CliRunner().invoke(main, ["report", str(sessions[0]), "-o", str(out)])
    assert r.exit_code == 0, r.output
    return out.read_text(encoding="utf-8")


def test_every_section_in_order(page):
    ids = [a["id"] for t, a in _parse(page).tags if t == "section"]
    assert ids == SECTION_IDS


def test_nothing_external_no_script_every_figure_a_png(page):
    p = _parse(page)
    assert not [t for t, _ in p.tags if t in ("script", "iframe", "object", "embed", "link")]
    assert all(a["href"].startswith("#") for t, a in p.tags if t == "a")
    imgs = [a["src"] for t, a in p.tags if t == "img"]
    assert len(imgs) == 4  # plan, sample spreads, convergence, residuals
    for src in imgs:
        head, _, data = src.partition(",")
        assert head == "data:image/png;base64"
        assert base64.b64decode(data, validate=True)[:8] == b"\x89PNG\r\n\x1a\n"
    assert "http://" not in page and "https://" not in page


def test_session_text_is_escaped(page):
    assert HOSTILE not in page and REASON not in page
    assert "<script>" not in page
    text = "".join(_parse(page).text)
    assert HOSTILE in text  # shown, as text
    assert REASON in text


def test_skipped_and_corrupted_poses_are_named(page):
    rows: list[list[str]] = []

    class Rows(HTMLParser):
        cells: list[str] = []
        in_td = False

        def handle_starttag(self, tag, attrs):
            if tag == "tr":
                self.cells = []
            if tag == "td":
                self.cells.append("")
                self.in_td = True

        def handle_data(self, data):
            if self.in_td:
                self.cells[-1] += data

        def handle_endtag(self, tag):
            self.in_td = self.in_td and tag != "td"
            if tag == "tr" and self.cells:
                rows.append(self.cells)

    Rows().feed(page)
    assert [str(SKIPPED), REASON] in rows
    outliers = [r for r in rows if len(r) == 2 and "marker translation" in r[1]]
    assert [r[0] for r in outliers] == [str(CORRUPTED)]


def test_stored_calibration_is_held_out_on_another_session(sessions, tmp_path):
    a, b = sessions
    calib = tmp_path / "c.yaml"
    assert CliRunner().invoke(main, ["solve", str(a), "-o", str(calib)]).exit_code == 0
    pages = {}
    for s in (a, b):
        out = tmp_path / f"{s.stem}.html"
        r = CliRunner().invoke(main, ["report", str(s), "--calib", str(calib), "-o", str(out)])
        assert r.exit_code == 0, r.output
        pages[s.stem] = "".join(_parse(out.read_text()).text)
    assert "IN-SAMPLE" in pages["a"]
    assert "IN-SAMPLE" not in pages["b"]
    assert "held out: none of them was solved on" in pages["b"]
    assert f"Stored in {calib}" in pages["b"]
    assert "stores no uncertainty" in pages["b"]


def test_output_rule(sessions, tmp_path):
    a, _ = sessions
    out = tmp_path / "r.html"
    out.write_text("keep")
    r = CliRunner().invoke(main, ["report", str(a), "-o", str(out)])
    assert r.exit_code != 0 and "--force" in r.output
    assert out.read_text() == "keep"
    r = CliRunner().invoke(main, ["report", str(a), "-o", str(a), "--force"])
    assert r.exit_code != 0 and "input" in r.output
    assert read_session(a).poses  # the session is untouched
