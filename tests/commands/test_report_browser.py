"""The report of `derive reproduce --quick` in a real browser (Debian's Chromium, headless):
``index.html`` copied alone into an empty directory renders, every image in it loads
(naturalWidth > 0, read back from the rendered DOM), the summary is on the first screen
and nothing is wider than the window; plus every embedded image decodes as a PNG, and a
screenshot of the first screen is taken.

Skipped only when no Chromium is installed (.ci/run installs it)."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess

import pytest
from test_report import report  # noqa: F401  (the quick run, shared with test_report)

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run",
         "--hide-scrollbars", "--window-size=1280,1000"]
PNG = b"\x89PNG\r\n\x1a\n"

# Appended to a copy of the page: once everything has loaded, write what the browser
# sees into the DOM, which --dump-dom prints.
PROBE = """<script>
window.addEventListener("load", () => {
  const out = document.createElement("pre");
  out.id = "probe";
  const summary = document.getElementById("summary").getBoundingClientRect();
  out.textContent = JSON.stringify({
    images: Array.from(document.images, i => [i.complete, i.naturalWidth, i.naturalHeight]),
    summaryTop: summary.top + window.scrollY,
    height: window.innerHeight,
    scrollWidth: document.documentElement.scrollWidth,
    width: window.innerWidth});
  document.body.appendChild(out);
});
</script>"""

needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed "
                                    "(apt-get install chromium; .ci/run does)")


def _chromium(*args, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([CHROMIUM, *FLAGS, *args], cwd=cwd, capture_output=True,
                          text=True, timeout=120)


def test_every_embedded_image_is_a_png(report):  # noqa: F811
    doc = (report[2] / "index.html").read_text(encoding="utf-8")
    sources = re.findall(r'<img src="([^"]+)"', doc)
    assert len(sources) == len(list((report[2] / "figures").glob("*.png")))
    for src in sources:
        assert src.startswith("data:image/png;base64,"), src[:40]
        data = base64.b64decode(src.split(",", 1)[1], validate=True)
        assert data.startswith(PNG) and len(data) > 5000


@needs_chromium
def test_page_alone_renders_with_every_image_loaded(report, tmp_path):  # noqa: F811
    doc = (report[2] / "index.html").read_text(encoding="utf-8")
    alone = tmp_path / "probe.html"            # no figures/ beside it
    alone.write_text(doc.replace("</body>", PROBE + "</body>"), encoding="utf-8")
    run = _chromium("--virtual-time-budget=10000", "--dump-dom", alone.as_uri(),
                    cwd=tmp_path)
    match = re.search(r'<pre id="probe">(.*?)</pre>', run.stdout, re.S)
    assert match, run.stderr[-2000:]
    seen = json.loads(match.group(1).replace("&quot;", '"'))
    assert len(seen["images"]) == doc.count("<img ") > 0
    for complete, width, height in seen["images"]:
        assert complete and width > 0 and height > 0
    assert seen["summaryTop"] < seen["height"]          # the summary on the first screen
    assert seen["scrollWidth"] <= seen["width"]         # nothing cut at the right edge


@needs_chromium
def test_first_screen_screenshot(report, tmp_path):  # noqa: F811
    page = tmp_path / "index.html"
    shutil.copy(report[2] / "index.html", page)
    shot = tmp_path / "first.png"
    run = _chromium(f"--screenshot={shot}", page.as_uri(), cwd=tmp_path)
    assert shot.is_file(), run.stderr[-2000:]
    data = shot.read_bytes()
    assert data.startswith(PNG)
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert (width, height) == (1280, 1000)
    assert len(data) > 20_000                   # text and tables, not a blank page


def test_summary_first_and_long_tables_last(report):  # noqa: F811
    doc = (report[2] / "index.html").read_text(encoding="utf-8")
    summary = doc.index('<section id="summary">')
    first_figure, last_figure = doc.index("<figure>"), doc.rindex("<figure>")
    assert summary < doc.index("<nav>") < first_figure
    folded = [m.start() for m in re.finditer(r"<details><summary>", doc)]
    assert folded and doc.count("rows)</summary>") >= 2
    for caption in ("Generated code against the NumPy reference",
                    "Equivalence checks (max differences)"):
        folded_table = re.search(rf"<details><summary>{re.escape(caption)} \(\d+ rows\)", doc)
        assert folded_table and folded_table.start() > last_figure, caption
    assert doc.rindex("<footer>") > max(folded)


def test_every_section_has_outcomes_in_the_summary(report):  # noqa: F811
    text = (report[2] / "results.md").read_text(encoding="utf-8")
    for paper in ("MPT3D", "GSM2D", "SSPRED", "MDKF", "GNSS", "derive"):
        assert re.search(rf"^\| {paper} \| .* \| (matched|differs|not comparable) \| ",
                         text, re.M), paper
    assert "Written by `derive reproduce --out " in text and "--quick" in text
    assert "**a quick run**" in text
    assert re.search(r"- \*\*date:\*\* \d{4}-\d\d-\d\dT", text)
