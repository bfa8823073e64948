"""The report in a real browser: headless Chromium (Debian's), network off, from a file:// URL.

Checks from the DOM that every table cell shows the value of results.json at the shown precision
(means recomputed from results.json), that every image decodes with a non-zero size, and that the
page asked nothing of any network. `.ci/run` installs chromium; playwright comes with the test extra.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from report_helpers import expected_text, result_values, rewrite_results, skip_output

from wcbench.bench.report import make_results_folders
from wcbench.reports import build_report

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync"]


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    if not Path(CHROMIUM).is_file():
        pytest.skip("chromium is not installed (apt-get install -y chromium; .ci/run does it)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (test extra)")
    profile = tmp_path_factory.mktemp("chromium-profile")
    with sync_api.sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(str(profile), executable_path=CHROMIUM, headless=True,
                                                        args=FLAGS, viewport={"width": 1400, "height": 1000})
        yield context
        context.close()


def test_report_in_headless_chromium_offline(small, tmp_path, browser):
    folders = list(small.values())
    rewrite_results(small["haze"], lambda d: skip_output(d, "scene_b", "rain", "sem_cs", "weights not installed"))
    out = tmp_path / "report.html"
    build_report(folders, out, animation_frames=4)
    page = browser.new_page()
    requests: list[str] = []
    blocked: list[str] = []

    def route(r):
        requests.append(r.request.url)
        if r.request.url.startswith("file://"):
            r.continue_()
        else:  # the network is off for the page: record and refuse anything else
            blocked.append(r.request.url)
            r.abort()

    page.route("**/*", route)
    page.goto(out.as_uri(), wait_until="load")
    page.evaluate("Promise.all([...document.images].map(i => i.decode().catch(() => null)))")
    page.screenshot(path=str(tmp_path / "report.png"), full_page=True)
    assert (tmp_path / "report.png").stat().st_size > 10_000
    assert blocked == [] and requests == [out.as_uri()]

    images = page.evaluate("[...document.images].map(i => [i.complete, i.naturalWidth, i.naturalHeight])")
    assert len(images) > 10
    assert all(done and w > 0 and h > 0 for done, w, h in images), images

    cells = page.evaluate("""[...document.querySelectorAll('td[data-output]')].map(td => ({
        method: td.dataset.method, scene: td.dataset.scene, weather: td.dataset.weather,
        output: td.dataset.output, text: td.querySelector('.v').textContent, title: td.title}))""")
    values = result_values(folders)
    numbers = dashes = 0
    for c in cells:
        cell = {"data-method": c["method"], "data-scene": c["scene"], "data-weather": c["weather"],
                "data-output": c["output"]}
        if c["text"] == "\u2013":
            dashes += 1
            assert c["title"], c  # a dash always says why
            assert expected_text(values, cell, 3) is None, c
        else:
            numbers += 1
            assert c["text"] == expected_text(values, cell, len(c["text"].split(".")[1])), c
    assert numbers > 100 and dashes > 0
    # bold (best) is rendered bold
    weight = page.evaluate("getComputedStyle(document.querySelector('td.r1 .v')).fontWeight")
    assert int(weight) >= 700
    page.close()


def test_every_table_fits_a_1400_px_page(tmp_path, browser):
    """Every weather (16 temporal columns) and a long method name: no table wider than the page's
    column at 1400 px (a wider one would scroll sideways inside its box)."""
    folders, _ = make_results_folders(tmp_path / "res", methods=("tint", "weathercity-long-name"), scenes=("scene_a",),
                                      weathers=("clear", "rain", "snow", "fog"), n_frames=3, size=(32, 18))
    out = tmp_path / "report.html"
    build_report(folders, out, frames=False)
    page = browser.new_page()
    page.goto(out.as_uri(), wait_until="load")
    page.evaluate("document.querySelectorAll('details').forEach(d => d.open = true)")
    widths = page.evaluate("""[...document.querySelectorAll('.table-wrap')].map(w => ({
        id: w.querySelector('table').id, table: w.querySelector('table').scrollWidth, box: w.clientWidth,
        page: document.documentElement.scrollWidth, columns: w.querySelectorAll('thead tr:last-child th').length}))""")
    page.close()
    assert any(w["id"] == "t-temporal" and w["columns"] == 16 for w in widths), widths
    assert all(w["table"] <= w["box"] <= 1400 for w in widths), [w for w in widths if w["table"] > w["box"]]
    assert all(w["page"] <= 1400 for w in widths)
