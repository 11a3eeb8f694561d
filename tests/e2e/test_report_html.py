"""The HTML report rendered in a real browser: Debian's headless Chromium driven through its
chromedriver (selenium). Checks the sections, that every figure decoded, and that the page
fetched nothing. ``.ci/run`` installs chromium and chromium-driver; on a machine without them
this test is skipped, saying why."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import pytest
from click.testing import CliRunner

from tmscal.cli import main

pytestmark = pytest.mark.e2e

#: the section ids and headings docs/report.md lists, in page order
SECTIONS = [("verdict", "Verdict"), ("rig", "Rig and devices"),
            ("plan", "Plan and its spread"), ("samples", "Samples per pose"),
            ("calibration", "Calibration"),
            ("errors", "Held-out errors"), ("convergence", "Convergence"),
            ("residuals", "Residuals by pose")]

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
#: flags that let Debian's chromium run headless as root in a container, offline
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--window-size=1200,900"]


@pytest.fixture
def browser(tmp_path: Path):
    webdriver = pytest.importorskip("selenium.webdriver",
                                    reason="selenium is not installed (test extra)")
    from selenium.webdriver.chrome.service import Service

    for exe, pkg in ((CHROMIUM, "chromium"), (CHROMEDRIVER, "chromium-driver")):
        if not Path(exe).exists():
            pytest.skip(f"{exe} not found: install Debian's {pkg} (apt-get install -y "
                        "chromium chromium-driver; .ci/run does)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for f in FLAGS + [f"--user-data-dir={tempfile.mkdtemp(dir=tmp_path)}"]:
        opts.add_argument(f)
    drv = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    yield drv
    drv.quit()


def test_report_renders_in_chromium(browser, tmp_path: Path):
    session, page = tmp_path / "sim.jsonl", tmp_path / "report.html"
    run = CliRunner().invoke
    assert run(main, ["simulate", "-o", str(session), "--poses", "60", "--seed", "5"]
               ).exit_code == 0
    r = run(main, ["report", str(session), "-o", str(page)])
    assert r.exit_code == 0, r.output

    browser.get(page.as_uri())
    found = browser.execute_script(
        "return Array.from(document.querySelectorAll('section')).map("
        "s => [s.id, s.querySelector('h2').innerText])")
    assert [tuple(x) for x in found] == SECTIONS
    images = browser.execute_script(
        "return Array.from(document.images).map(i => [i.alt, i.complete, i.naturalWidth, "
        "i.naturalHeight])")
    # a simulated session records no sample spreads: no figure of them
    assert sorted(i[0] for i in images) == ["convergence curve", "plan spread",
                                            "residuals by pose"]
    for alt, complete, w, h in images:
        assert complete and w > 100 and h > 100, f"figure {alt!r} did not decode"
    fetched = browser.execute_script(
        "return performance.getEntriesByType('resource').map(e => e.name)")
    assert fetched == []
    shot = tmp_path / "report.png"
    assert browser.save_screenshot(str(shot))
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
