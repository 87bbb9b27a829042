"""report.html and campaign.html in a real browser (issue 29).

Headless Chromium, driven through Selenium's WebDriver (Debian's ``chromium`` and
``chromium-driver``; .ci/run installs them where it can), opens each page at
1400x900 and asks the DOM the browser built: no horizontal overflow of the page,
every table's header as wide as each of its rows (colspans counted), no empty
header row, and the witness ρ* row not shaded like a counterexample. The pages
are the real ones: the default video's report (the README's main job) and a
small campaign's summary. Screenshots go to ``$LESMC_ARTIFACTS`` (CI keeps them)
or the test's temporary directory. tests/html_tables.py checks the same table
structure without a browser.
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
from cli_run import lesmc
from note_verdicts import contradictions

from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video

webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is a test extra")

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None or DRIVER is None,
    reason="Chromium and chromedriver are not installed (Debian: chromium chromium-driver; "
    ".ci/run installs them)",
)

#: The problems the browser sees, as text (an empty list: none).
PROBLEMS_JS = """
const out = [];
const root = document.documentElement;
if (root.scrollWidth > window.innerWidth) {
  out.push(`the page overflows horizontally: ${root.scrollWidth} px in ${window.innerWidth}`);
}
const width = r => Array.from(r.cells).reduce((n, c) => n + c.colSpan, 0);
const isHead = r => r.cells.length > 0 && Array.from(r.cells).every(c => c.tagName === 'TH');
document.querySelectorAll('table').forEach((t, k) => {
  const rows = Array.from(t.rows);
  const heads = [];
  while (rows.length && isHead(rows[0])) heads.push(rows.shift());
  heads.forEach(r => {
    const empty = Array.from(r.cells).every(c => !c.textContent.trim());
    if (empty) out.push(`table ${k}: empty header row`);
  });
  if (!heads.length) return;
  const w = Math.max(...heads.map(width));
  rows.forEach((r, i) => {
    const n = width(r);
    if (n !== w) out.push(`table ${k}, row ${i + 1}: ${n} cells under a header of ${w}`);
  });
});
const shade = r => getComputedStyle(r).backgroundColor;
const rows = Array.from(document.querySelectorAll('tr'));
const roleOf = r => r.cells.length ? r.cells[r.cells.length - 1].textContent : '';
const cex = new Set(rows.filter(r => roleOf(r).includes('counterexample')).map(shade));
rows.filter(r => roleOf(r).includes('ρ*') && !roleOf(r).includes('counterexample')).forEach(r => {
  if (cex.has(shade(r))) out.push(`a ρ* row is shaded like a counterexample: ${roleOf(r)}`);
});
return out;
"""


#: Each design section as the browser shows it: its notes and, per property, the verdict
#: cell of the first row whose header is the property (Table 4).
NOTES_JS = """
const out = [];
document.querySelectorAll('section').forEach(sec => {
  const h = sec.querySelector("h2[id^='design-']");
  if (!h) return;
  const notes = Array.from(sec.querySelectorAll('p.note')).map(p => p.innerText.trim());
  const verdicts = {};
  sec.querySelectorAll('tr').forEach(tr => {
    const th = tr.querySelector('th');
    const td = th && th.nextElementSibling;
    const name = th && th.innerText.trim();
    if (td && td.tagName === 'TD' && !(name in verdicts)) verdicts[name] = td.innerText.trim();
  });
  out.push({design: h.id.slice('design-'.length), notes: notes, verdicts: verdicts});
});
return out;
"""


def _notes_against_verdicts(browser: object, doc: dict[str, Any]) -> list[str]:
    """Issue 56, item 1, read as a person reads the page: every note beside its property's
    verdict in the same design section, and that verdict the results file's final one."""
    shown = {s["design"]: s for s in browser.execute_script(NOTES_JS)}  # type: ignore[attr-defined]
    problems = []
    for run in doc["runs"]:
        section = shown[run["design"]]
        for r in run["results"]:
            name = r["property"]
            mine = [n.removeprefix(name + ": ") for n in section["notes"]
                    if n.startswith(name + ": ")]  # fmt: skip
            problems += [f"{run['design']}: {p}" for p in contradictions(r["status"], mine)]
            cell = re.sub(r"^holds \(vacuous: .*\)$", "holds (vacuous)",
                          section["verdicts"].get(name, ""), flags=re.S)  # fmt: skip
            if cell != r["status"]:
                problems.append(f"{run['design']}: {name} shows {cell!r}, results say "
                                f"{r['status']!r}")  # fmt: skip
    return problems


@pytest.fixture(scope="module")
def browser() -> object:
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    opts.binary_location = str(CHROMIUM)
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1400,900"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(str(DRIVER)), options=opts)
    driver.set_window_size(1400, 900)
    yield driver
    driver.quit()


def _artifacts(tmp_path: Path) -> Path:
    where = Path(os.environ.get("LESMC_ARTIFACTS") or tmp_path)
    where.mkdir(parents=True, exist_ok=True)
    return where


def _look(browser: object, page: Path, shots: Path, name: str) -> list[str]:
    """Open ``page``, save its screenshots, return the problems the browser finds."""
    browser.get(page.as_uri())  # type: ignore[attr-defined]
    browser.save_screenshot(str(shots / f"{name}-1400x900.png"))  # type: ignore[attr-defined]
    full = browser.execute_cdp_cmd(  # type: ignore[attr-defined]
        "Page.captureScreenshot", {"captureBeyondViewport": True, "format": "png"}
    )
    (shots / f"{name}-full.png").write_bytes(base64.b64decode(full["data"]))
    assert browser.execute_script("return document.readyState") == "complete"  # type: ignore[attr-defined]
    problems: list[str] = browser.execute_script(PROBLEMS_JS)  # type: ignore[attr-defined]
    return problems


def test_the_default_videos_report_is_sound_in_a_browser(
    browser: object,
    default_verify: tuple[Path, subprocess.CompletedProcess[str], list[float]],
    tmp_path: Path,
) -> None:
    out, r, _ = default_verify
    page = out / "report.html"
    assert page.is_file(), r.stderr
    html = page.read_text()
    assert "ρ*" in html and "counterexample" in html  # the checks below have rows to look at
    assert _look(browser, page, _artifacts(tmp_path), "report") == []
    doc = json.loads((out / "results.json").read_text())
    assert _notes_against_verdicts(browser, doc) == []
    # the check can fail: a results file whose first verdict differs from the page's
    first = doc["runs"][0]["results"][0]
    first["status"] = "holds" if first["status"] != "holds" else "unknown"
    assert _notes_against_verdicts(browser, doc) != []


def test_a_campaign_summary_is_sound_in_a_browser(browser: object, tmp_path: Path) -> None:
    video = tmp_path / "tiny"
    write_video(SynthConfig(frames=11, width=448, height=448, seed=4, density=3.0), video)
    out = tmp_path / "camp"
    r = lesmc("campaign", str(video), "--out", str(out), "--workers", "0",
              "--windows", "2..3:0..1", "--targets", "3", "--no-truth")  # fmt: skip
    assert r.returncode in (0, 1, 3) and "Traceback" not in r.stderr, r.stderr
    assert _look(browser, out / "campaign.html", _artifacts(tmp_path), "campaign") == []


def test_the_checks_catch_a_broken_page(browser: object, tmp_path: Path) -> None:
    """The browser checks themselves: each problem they look for is found."""
    page = tmp_path / "broken.html"
    page.write_text(
        "<!DOCTYPE html><html><head><style>tr.bad{background:#fdecea}</style></head><body>"
        "<div style='width:3000px'>wide</div>"
        "<table><tr><th></th><th></th></tr><tr><th>a</th><th>b</th><th>c</th></tr>"
        "<tr><td>1</td><td>2</td></tr>"
        "<tr class='bad'><td>x</td><td>y</td><td>p counterexample</td></tr>"
        "<tr class='bad'><td>x</td><td>y</td><td>p ρ*</td></tr></table></body></html>"
    )
    found = _look(browser, page, tmp_path, "broken")
    assert any("overflows horizontally" in p for p in found), found
    assert any("empty header row" in p for p in found), found
    assert any("2 cells under a header of 3" in p for p in found), found
    assert any("ρ* row is shaded like a counterexample" in p for p in found), found
