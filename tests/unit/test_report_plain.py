"""The report shows values as a reader writes them (issue 24, item 6): no Python reprs (None,
True, {'marker': 1, …}) from the session header or a device's identity, no negative zero in a
table or a matrix, and whole-number ticks on the axes that count poses or index them."""

from __future__ import annotations

import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.report.text import format_matrix, number, plain_value
from tmscal.session import make_header, records_from_arrays, write_session
from tmscal.sim import Noise, simulate

pytest.importorskip("matplotlib")


class _Text(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.parts: list[str] = []

    def handle_data(self, data: str) -> None:
        self.parts.append(data)


def _session(path: Path, n: int = 12) -> Path:
    """A short simulated session whose header holds what a real one does: a device identity
    with a mapping (NDI port handles) and empty values, sampling settings left empty, and a
    first commanded pose exactly at P0 (offsets of 0 and -0)."""
    truth, d = simulate(n, np.random.default_rng(4), noise=Noise())
    header = make_header(
        ["marker", "probe"], truth=truth.as_dict(), config={"name": "plain"},
        devices={"tracker": {"driver": "ndi", "handles": {"marker": 1, "probe": 2},
                             "serial": None, "wired": False}},
        sampling={"samples": 10, "still_tol_mm": None, "sem_mm": None},
        plan={"kind": "eq14", "poses": n, "seed": 1, "start": None,
              "p0": d["commanded"][0].tolist()})
    return write_session(path, header, records_from_arrays(d["A"], d["marker"], d["probe"],
                                                           d["commanded"]))


def test_report_has_no_python_reprs_and_no_negative_zero(tmp_path):
    out = tmp_path / "r.html"
    r = CliRunner().invoke(main, ["report", str(_session(tmp_path / "s.jsonl")), "-o",
                                  str(out)])
    assert r.exit_code == 0, r.output
    p = _Text()
    p.feed(out.read_text(encoding="utf-8"))
    text = " ".join(p.parts)
    for bad in (r"\bNone\b", r"\bTrue\b", r"\bFalse\b", r"\{'", r"'\}",
                r"(?<![\w.])-0(\.0+)?(?![\d.])"):
        m = re.search(bad, text)
        assert m is None, f"{bad!r} in the report: …{text[max(0, m.start() - 60):m.end() + 30]}…"
    assert "handles marker 1, probe 2" in " ".join(text.split()) or \
        "marker 1, probe 2" in text
    assert "sem_mm none" in text


def test_plain_value_and_number():
    assert plain_value(None) == "none"
    assert plain_value({"marker": 1, "probe": 2}) == "marker 1, probe 2"
    assert plain_value({"a": {"b": None}, "c": [1.0, -0.0], "d": True}) == \
        "a (b none), c [1, 0], d yes"
    assert plain_value({}) == "none"
    assert number(-1e-9, ".1f") == "0.0" and number(-0.04, ".1f") == "0.0"
    assert number(-0.06, ".1f") == "-0.1" and number(-1e-20) == "-1e-20"
    assert number(-1e-9, ">11.5f") == "    0.00000"
    assert "-0.0" not in format_matrix(np.diag([1.0, -1e-12, 1.0, 1.0]))


def _ticks_of(monkeypatch: pytest.MonkeyPatch, draw) -> list:
    """The axes of the figure ``draw(path)`` saves (captured at savefig)."""
    from matplotlib.figure import Figure

    seen: list = []
    orig = Figure.savefig

    def keep(self, *a, **k):
        self.canvas.draw()
        seen.extend(self.axes)
        return orig(self, *a, **k)

    monkeypatch.setattr(Figure, "savefig", keep)
    draw()
    return seen


def _whole(values) -> bool:
    return all(float(v).is_integer() for v in values)


def test_pose_axes_have_whole_number_ticks(tmp_path, monkeypatch):
    from tmscal.report.plots import plot_residuals, plot_study

    idx = [3, 4, 5, 6]  # few poses: a default locator puts ticks at 3.5, 4.5, …
    res = {"index": idx, "marker": {"trans_mm": [0.1, 0.2, 0.15, 0.1],
                                    "rot_deg": [0.01, 0.02, 0.01, 0.03]}}
    axes = _ticks_of(monkeypatch, lambda: plot_residuals(res, 4, str(tmp_path / "r.png"),
                                                         "t"))
    lo, hi = axes[1].get_xlim()
    assert _whole(t for t in axes[1].get_xticks() if lo <= t <= hi)
    study = {"n": [3, 4, 5, 6], "n_test": 10,
             "curves": {"qr36": {"e_t_mm": [1.0, 0.5, 0.4, 0.3],
                                 "theta_t_deg": [0.5, 0.3, 0.2, 0.2]}}}
    monkeypatch.undo()
    axes = _ticks_of(monkeypatch, lambda: plot_study(study, str(tmp_path / "s.png")))
    for ax in axes[:2]:
        lo, hi = ax.get_xlim()
        assert _whole(t for t in ax.get_xticks() if lo <= t <= hi)
