"""Hostile text in every output tmscal writes (issue 22, items 9 and 10): file names, a rig
config's ports and ROM paths, device names and identities, a calibration's method: the XML
export parses (ElementTree) with the text intact, the HTML report parses (html.parser) with
the text shown and no markup added, and no output carries a control character or a bidi
override; those are shown as visible escapes (\\x1b, \\u202e)."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.escape import html_text, visible, xml_attr, xml_comment, xml_text
from tmscal.session import make_header, read_session, write_session

from ..rigs import simulated

#: hostile names: XML comment breakers, a CDATA end, quotes and markup, controls (ESC, BEL,
#: SOH, DEL, a C1 control), the right-to-left override, a newline that would start a line
#: → how each is shown (written out here by hand)
SHOWN = {"a--b": "a--b", "trailing-": "trailing-", "]]>": "]]>",
         "q\"u'o<t>e&s": "q\"u'o<t>e&s",
         "ctl\x01\x1b[2J\x07\x7f\x85": r"ctl\x01\x1b[2J\x07\x7f\x85",
         "rlo\u202egnp.exe": r"rlo\u202egnp.exe",
         "nl\nParameters: 1 2 3": r"nl\x0aParameters: 1 2 3"}
HOSTILE = list(SHOWN)

#: what must never reach an output: C0 controls but tab/newline/CR, DEL, C1, bidi controls
_RAW = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\u061c\u200e\u200f\u202a-\u202e"
                  "\u2066-\u2069\u2028\u2029]")


def run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def calib(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("esc")
    run("simulate", "-o", d / "s.jsonl", "--poses", 30, "--seed", 3)
    run("solve", d / "s.jsonl", "-o", d / "c.yaml", "--folds", 2)
    return d / "c.yaml"


def _hostile_calib(calib: Path, tmp_path: Path, name: str) -> Path:
    """The calibration under a hostile file name, its rig config's port and ROM paths and
    its session path hostile too."""
    doc = yaml.safe_load(calib.read_text())
    doc["provenance"]["config"] = {"tracker": {
        "driver": "ndi", "port": f"/dev/{name}", "baud": 115200, "frame_rate_hz": 60,
        "tools": {"marker": f"/roms/{name}.rom", "probe": f"/roms/p{name}.rom"}}}
    doc["session"]["path"] = f"/data/{name}.jsonl"
    p = tmp_path / f"{name}.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def _clean(text: str) -> None:
    assert not _RAW.findall(text), _RAW.findall(text)


@pytest.mark.parametrize("name", HOSTILE)
def test_plus_export_parses_with_hostile_names(calib, tmp_path, name):
    src = _hostile_calib(calib, tmp_path, name)
    out = tmp_path / "plus.xml"
    run("export", src, "--format", "plus", "-o", out)
    text = out.read_text(encoding="utf-8")
    _clean(text)
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    root = ET.fromstring(text.encode("utf-8"), parser=parser)  # well-formed XML 1.0
    head = text.split("<PlusConfiguration", 1)[0]
    assert head.count("<!--") == 1 and head.count("-->") == 1
    comment = head.split("<!--", 1)[1].split("-->", 1)[0]
    assert "--" not in comment and not comment.endswith("-")
    assert f"{SHOWN[name]}.yaml" in comment.replace("- ", "-")  # '--' split as '- -'
    dev = root.find("./DataCollection/Device")
    roms = {s.get("Id"): s.get("RomFile") for s in dev.findall("./DataSources/DataSource")}
    if "\n" in name:  # the NDI driver's settings refuse a port with a line break: the
        # recorded tracker is not read, and the device block carries placeholders
        assert dev.get("SerialPort").startswith("CHECK")
        assert all(r.startswith("CHECK") for r in roms.values())
        return
    assert dev.get("SerialPort") == f"/dev/{SHOWN[name]}"
    assert roms == {"CoilMarker": f"/roms/{SHOWN[name]}.rom",
                    "Probe": f"/roms/p{SHOWN[name]}.rom"}


@pytest.mark.parametrize("name", HOSTILE)
def test_line_comment_exports_stay_one_line(calib, tmp_path, name):
    """The ITK file and the easy_handeye YAML name the calibration file in '#' comments: a
    newline in the name must not start a line of the file's own (a forged 'Parameters:')."""
    src = _hostile_calib(calib, tmp_path, name)
    tfm = tmp_path / "Z.tfm"
    run("export", src, "--format", "itk", "-o", tfm)
    text = tfm.read_text()
    _clean(text)
    body = [ln.split(":")[0] for ln in text.splitlines() if not ln.startswith("#")]
    assert body == ["Transform", "Parameters", "FixedParameters"]
    assert f"{SHOWN[name]}.yaml" in text and f"/data/{SHOWN[name]}.jsonl" in text
    eh = tmp_path / "eh.yaml"
    run("export", src, "--format", "easy-handeye", "-o", eh)
    text = eh.read_text()
    _clean(text)
    assert set(yaml.safe_load(text)) == {"parameters", "transformation"}
    assert f"{SHOWN[name]}.yaml" in text


class _Text(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)

    def handle_data(self, data):
        self.text.append(data)


MARKUP = '<b class="x">bold</b>'
CONTROLS = "esc\x1b[31m bel\x07 rlo\u202eevil"


@pytest.fixture(scope="module")
def page(tmp_path_factory) -> str:
    """A report of a session whose device names (the kinds), identity keys and values, config
    name and skip reason carry markup, ESC, BEL and U+202E."""
    truth, d = simulated(30, seed=4)
    from tmscal.session import records_from_arrays
    recs = records_from_arrays(d["A"], d["marker"], d["probe"], d["commanded"])
    recs[3].B = recs[3].C = None
    recs[3].skipped = f"reason {CONTROLS} {MARKUP}"
    header = make_header(
        ["marker", "probe"], truth=truth.as_dict(), config={"name": f"cfg {CONTROLS}"},
        devices={f"robot {MARKUP}": {f"model {MARKUP}": f"UR5e {CONTROLS}"},
                 f"tracker {CONTROLS}": {"serial": f"P9-{MARKUP}"}})
    dd = tmp_path_factory.mktemp("page")
    write_session(dd / "s.jsonl", header, recs)
    run("report", dd / "s.jsonl", "-o", dd / "r.html", "--folds", 2)
    return (dd / "r.html").read_text(encoding="utf-8")


def test_report_device_names_and_identities_are_escaped(page):
    p = _Text()
    p.feed(page)
    assert "b" not in p.tags  # no markup from the session
    text = "".join(p.text)
    for s in (f"robot {MARKUP}", f"model {MARKUP}", f"P9-{MARKUP}"):
        assert s in text  # shown as text
    assert MARKUP not in page


def test_report_shows_controls_and_bidi_overrides_as_visible_escapes(page):
    _clean(page)
    p = _Text()
    p.feed(page)
    text = "".join(p.text)
    shown = r"esc\x1b[31m bel\x07 rlo\u202eevil"
    for s in (f"cfg {shown}", f"tracker {shown}", f"UR5e {shown}", f"reason {shown}"):
        assert s in text


def test_solve_check_text_output_shows_controls_as_escapes(calib, tmp_path):
    """The text `solve --calib` prints names the calibration's method, session and date from
    the file: controls and bidi overrides are shown escaped, not sent to the terminal."""
    doc = yaml.safe_load(calib.read_text())
    doc["method"] = "qr36\x1b]0;title\x07\u202e"
    doc["session"]["path"] = "/data/\x1b[2Js.jsonl"
    doc["created"] = "2024\u202e-01-01"
    bad = tmp_path / "c.yaml"
    bad.write_text(yaml.safe_dump(doc))
    session = Path(read_session(calib.parent / "s.jsonl").path)
    r = run("solve", session, "--calib", bad)
    _clean(r.output)
    assert r"\x1b]0;title\x07\u202e" in r.output.lower() and r"\x1b[2J" in r.output


def test_the_helpers_by_character_class():
    for s in HOSTILE + [CONTROLS, "\ud800 lone", "\ufffe\uffff", "tab\there"]:
        comment, attr, text, h = xml_comment(s), xml_attr(s), xml_text(s), html_text(s)
        ET.fromstring(f"<a b={attr}><!--{comment}-->{text}</a>".encode("utf-8", "strict"))
        for out in (comment, attr, text, h, visible(s)):
            _clean(out)
        assert "--" not in comment and not comment.endswith("-")
        p = _Text()
        p.feed(f'<p title="{h}">{h}</p>')
        assert p.tags == ["p"] and "".join(p.text) == visible(s)
    assert ET.fromstring(f"<a b={xml_attr('tab	here')}/>").get("b") == "tab\there"
    assert visible("a\nb", newlines=True) == "a\nb" and visible("a\nb") == r"a\x0ab"


def test_report_of_a_hostile_stored_calibration_is_clean(calib, tmp_path):
    """`report --calib`: the calibration's method (in the <pre> tables and the text above
    them), its file name, session path and date come from the file."""
    doc = yaml.safe_load(calib.read_text())
    doc["method"] = f"qr36 {MARKUP} {CONTROLS}"
    doc["session"] = {"path": f"/data/{CONTROLS}.jsonl", "sha256": "0" * 64}  # held out
    doc["created"] = f"2024 {MARKUP}"
    bad = tmp_path / "rlo\u202ec.yaml"
    bad.write_text(yaml.safe_dump(doc))
    out = tmp_path / "r.html"
    run("report", calib.parent / "s.jsonl", "--calib", bad, "-o", out)
    page = out.read_text(encoding="utf-8")
    _clean(page)
    assert MARKUP not in page
    p = _Text()
    p.feed(page)
    assert "b" not in p.tags
    text = "".join(p.text)
    shown = r"esc\x1b[31m bel\x07 rlo\u202eevil"
    # the tables name the method in capitals: the escapes made after
    method = "QR36 " + MARKUP.upper() + r" ESC\x1b[31M BEL\x07 RLO\u202eEVIL"
    assert f"errors: the stored {method} calibration" in text  # the <pre> error table
    assert f"/data/{shown}.jsonl" in text and f"2024 {MARKUP}" in text
    assert r"rlo\u202ec.yaml" in text


def test_value_text_writes_mappings_and_lists_as_the_configs_do() -> None:
    """A device identity's values on a line of output: no Python repr (quotes, np.float64),
    control characters made visible."""
    import numpy as np

    from tmscal.escape import value_text

    assert value_text({"marker": 1, "probe": 2}) == "{marker: 1, probe: 2}"
    assert value_text([0.0, np.float64(0.5)]) == "[0.0, 0.5]"
    assert value_text({"tools": {"marker": [1, 2]}}) == "{tools: {marker: [1, 2]}}"
    assert value_text("P6-00001") == "P6-00001"
    assert value_text({"name": "a\x1b[2Jb"}) == "{name: a\\x1b[2Jb}"
