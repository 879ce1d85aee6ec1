"""The report as a person sees it: report.html rendered in headless Chromium (every figure
loads, nothing overflows the page), and report.md holding the same tables as the page.

Chromium is the Debian package `chromium` (`.ci/run` installs it). Outside CI the browser
test skips with a one-line reason when it is missing; under CI (CI=true) it fails.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest
from click.testing import CliRunner

from piezopress.piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_runs"

#: Read back by the probe: figures, the page's and the viewport's widths, and every element wider than the page.
PROBE = """<pre id="piezopress-probe"></pre><script>
window.addEventListener('load', () => {
  const vw = window.innerWidth;
  const wide = [...document.body.querySelectorAll('*')].filter(e => {
    if (e.closest('.table-wrap') && !e.classList.contains('table-wrap')) return false;  // scrolls inside its wrapper
    const r = e.getBoundingClientRect(); return r.width > 0 && (r.right > vw + 0.5 || r.left < -0.5);
  }).map(e => e.tagName + (e.id ? '#' + e.id : ''));
  document.getElementById('piezopress-probe').textContent = JSON.stringify({
    scrollWidth: document.documentElement.scrollWidth, innerWidth: vw, wide: wide,
    images: [...document.images].map(i => ({
        alt: i.alt, complete: i.complete, width: i.naturalWidth, height: i.naturalHeight,
        shown: i.getBoundingClientRect().width, box: i.parentElement.getBoundingClientRect().width}))});
});
</script>"""


def chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.fixture(scope="module")
def sample_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("browser") / "report"
    res = CliRunner().invoke(
        cli,
        [
            "report",
            "--characterization",
            str(SAMPLES / "characterization"),
            "--validation",
            str(SAMPLES / "validation"),
            "--bundle",
            str(SAMPLES / "bundle.json"),
            "--diagnosis",
            str(SAMPLES / "diagnosis"),
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    return out


def render(browser: str, page: Path, width: int, tmp_path: Path) -> dict:
    """The probe's findings on ``page`` at ``width`` px (a copy with the probe appended; the report holds no script)."""
    probe = tmp_path / f"probe-{width}.html"
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", PROBE + "\n</body>"), encoding="utf-8")
    done = subprocess.run(
        [
            browser,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            f"--window-size={width},2000",
            "--virtual-time-budget=10000",
            "--dump-dom",
            probe.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    m = re.search(r'<pre id="piezopress-probe">(.*?)</pre>', done.stdout, re.S)
    assert m and m.group(1), f"chromium gave no probe result (exit {done.returncode}): {done.stderr[-500:]}"
    return json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&").replace("&lt;", "<").replace("&gt;", ">"))


@pytest.mark.integration
@pytest.mark.parametrize("width", [1300, 900])
def test_every_figure_loads_and_nothing_overflows_the_page(sample_report, tmp_path, width):
    browser = chromium()
    if browser is None:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("chromium is missing under CI: .ci/run installs it (apt-get install -y chromium)")
        pytest.skip("chromium not installed (apt-get install -y chromium); the page was not rendered")
    found = render(browser, sample_report / "report.html", width, tmp_path)
    figures = sorted(p.name for p in sample_report.glob("*.png"))
    assert len(found["images"]) == len(figures) >= 12, (found["images"], figures)
    for img in found["images"]:
        # loaded: decoded to its full size (a broken data URI decodes to 0 x 0), and shown within its figure
        assert img["complete"] and img["width"] >= 800 and img["height"] >= 300, img
        assert 0 < img["shown"] <= img["box"] + 0.5, img
    assert found["scrollWidth"] <= found["innerWidth"], found
    assert found["wide"] == [], found["wide"]


class _Tables(HTMLParser):
    """The cells of every table of an HTML page, as text."""

    def __init__(self):
        super().__init__()
        self.tables: list[list[list[str]]] = []
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self.tables[-1].append([])
        elif tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1][-1].append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def markdown_tables(text: str) -> list[list[list[str]]]:
    tables, current = [], None
    for line in text.splitlines():
        if line.startswith("|"):
            cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
            if all(re.fullmatch(r"-+:?", c) for c in cells):
                continue  # the rule under the header
            if current is None:
                current = []
                tables.append(current)
            current.append([re.sub(r"`([^`]*)`", r"\1", c) for c in cells])
        else:
            current = None
    return tables


@pytest.mark.integration
def test_the_markdown_holds_the_same_tables_as_the_page(sample_report):
    parser = _Tables()
    parser.feed((sample_report / "report.html").read_text(encoding="utf-8"))
    md = markdown_tables((sample_report / "report.md").read_text(encoding="utf-8"))
    assert len(parser.tables) >= 8  # verdict, warnings, Table 6.13, characterization, validation, model quality, ...
    assert md == parser.tables


@pytest.mark.integration
def test_the_page_opens_with_the_verdict_and_links_every_section(sample_report):
    page = (sample_report / "report.html").read_text(encoding="utf-8")
    md = (sample_report / "report.md").read_text(encoding="utf-8")
    ids = re.findall(r'<h2 id="([^"]+)"', page)
    links = re.findall(r'<nav class="toc">.*?</nav>', page, re.S)[0]
    assert ids and re.findall(r'href="#([^"]+)"', links) == ids and ids[0] == "verdict"
    assert [f"(#{i})" in md for i in ids] == [True] * len(ids)
    # the verdict and the provenance come before any other section
    head = md.split("\n## ")[1]
    assert head.startswith("Verdict") and "Provenance: Rig thesis press (virtual)" in head and "backend virtual" in head
    assert re.search(r"\*\*(PASS|FAIL|INCOMPLETE): ", head)
