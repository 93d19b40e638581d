"""report.html in a real browser: headless Chromium (Debian's chromium + chromium-driver, driven
by selenium) loads the report of a small run, and the table, a box plot and both replays render
without console errors; moving the step slider redraws the replay. Screenshots go to
``$PACKLAB_SCREENSHOTS`` (default: the test's temporary directory).

Skipped where no Chromium, chromedriver or selenium is found (CI installs them: .ci/run).
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import pytest
from bench_helpers import write_tiny_suite
from report_helpers import sloppy_policy, small_run

from packlab.bench.html_report import run_html
from packlab.bench.report import load_run
from packlab.sim.pose_log import poses_after
from packlab.viz.report_html import embedded_data

webdriver = pytest.importorskip("selenium.webdriver")
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import Select

pytestmark = pytest.mark.browser

CHROMIUM = os.environ.get("PACKLAB_CHROMIUM") or next(
    filter(None, map(shutil.which, ("chromium", "chromium-browser", "google-chrome"))), None
)
CHROMEDRIVER = os.environ.get("PACKLAB_CHROMEDRIVER") or shutil.which("chromedriver")
MISSING = [
    name for name, found in (("chromium", CHROMIUM), ("chromedriver", CHROMEDRIVER)) if not found
]
if MISSING:  # name what is missing: a browser without its driver is the common case
    pytest.skip(
        f"no {' and no '.join(MISSING)} (apt-get install chromium chromium-driver)",
        allow_module_level=True,
    )

#: WebGL without a GPU (SwiftShader) and no sandbox (CI runs as root); a fixed window size so
#: screenshots are comparable.
CHROME_ARGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-dev-shm-usage",
    "--enable-unsafe-swiftshader",
    "--window-size=1400,1100",
)


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """A small run's report.html (4 tiny cases x 2 seeds, DBLF and a policy that makes invalid
    steps), and the records it was built from."""
    tmp = tmp_path_factory.mktemp("report")
    cases = write_tiny_suite(tmp)
    with sloppy_policy():
        small_run(cases, tmp / "run")
    run = load_run(tmp / "run")
    html = run_html(run.config, run.records, run.cases, generated="2026-01-01 00:00:00 UTC")
    path = tmp / "run" / "report.html"
    path.write_text(html, encoding="utf-8")
    return path, embedded_data(html)


@pytest.fixture(scope="module")
def browser():
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in CHROME_ARGS:
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))
    try:
        yield driver
    finally:
        driver.quit()


def _shots(tmp_path: Path) -> Path:
    out = Path(os.environ.get("PACKLAB_SCREENSHOTS") or tmp_path / "screenshots")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _wait(driver, script: str, timeout: float = 30.0):
    """Poll ``return <script>`` until it is truthy (the page renders asynchronously)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = driver.execute_script(f"return {script}")
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {script}")


def _severe(driver) -> list[str]:
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def _vertices(driver, pane: str) -> int:
    """Vertices of the packed boxes' mesh in a replay pane (8 per box)."""
    return driver.execute_script(
        f"var d = document.getElementById('{pane}-scene').data;"
        "return d[1].visible === false ? 0 : d[1].x.length;"
    )


def test_report_renders_and_replays_in_chromium(report, browser, tmp_path):
    path, data = report
    shots = _shots(tmp_path)
    browser.get(path.as_uri())
    _wait(browser, "window.packlabReport && window.packlabReport.ready")
    assert browser.execute_script("return window.packlabReport.errors") == []
    assert _severe(browser) == []

    # The table: one row per method, sortable by a click on a column header.
    rows = browser.find_elements(By.CSS_SELECTOR, "#results-table tbody tr")
    assert [r.find_elements(By.TAG_NAME, "td")[0].text for r in rows] == ["DBLF", "test-sloppy"]
    overall = browser.find_element(By.ID, "results-headline")  # Average Overall, column 1
    assert overall.get_attribute("data-col") == "1" and overall.text == "Overall"
    overall.click()
    overall.click()  # descending: the better method first
    first = browser.find_element(By.CSS_SELECTOR, "#results-table tbody tr td").text
    assert first == "DBLF"
    # A box plot: one box trace per (level, method), drawn as SVG.
    _wait(browser, "document.querySelectorAll('#box-plot g.trace.boxes').length")
    assert browser.execute_script(
        "return document.querySelectorAll('#box-plot g.trace.boxes').length"
    ) == len(data["levels"]) * len(data["methods"])
    # Both replays: a WebGL scene each, opened on the final packing.
    for pane in ("pane-a", "pane-b"):
        assert browser.find_elements(By.CSS_SELECTOR, f"#{pane}-scene canvas")
    n_steps = int(browser.find_element(By.ID, "pane-a-slider").get_attribute("max"))
    assert _vertices(browser, "pane-a") > 0
    browser.find_element(By.ID, "results").screenshot(str(shots / "report_table.png"))
    browser.find_element(By.ID, "boxes").screenshot(str(shots / "report_boxes.png"))
    _replay_shot(browser, shots / "report_replay_final.png")

    # Move the step slider (keyboard, as a user would): home, then two steps right.
    slider = browser.find_element(By.ID, "pane-a-slider")
    slider.send_keys(Keys.HOME)
    slider.send_keys(Keys.ARROW_RIGHT, Keys.ARROW_RIGHT)
    _wait(browser, "document.getElementById('pane-a-step').textContent.indexOf('step 3 /') === 0")
    case = data["cases"][
        browser.execute_script("return Number(document.getElementById('r-case').value)")
    ]
    method = browser.execute_script("return window.packlabReport.panes['pane-a'].m")
    episode = next(
        e
        for e in data["episodes"]
        if e["m"] == method and data["cases"][e["c"]] is case and e["s"] == 0
    )
    expected = len(poses_after([s[4] for s in episode["steps"]], 2))
    _wait(browser, f"document.getElementById('pane-a-scene').data[1].x.length === {8 * expected}")
    # The other pane follows (the sliders are linked by default).
    assert browser.find_element(By.ID, "pane-b-step").text.startswith("step 3 /")
    assert n_steps == len(episode["steps"])
    _replay_shot(browser, shots / "report_replay_step3.png")
    assert _severe(browser) == []


def test_case_browser_opens_an_invalid_step(report, browser, tmp_path):
    """Filter the case browser to the sloppy policy, open its worst episode, go to its
    out-of-bounds step: marked invalid, the object set aside."""
    path, _ = report
    browser.get(path.as_uri())
    _wait(browser, "window.packlabReport && window.packlabReport.ready")
    Select(browser.find_element(By.ID, "f-method")).select_by_value("1")
    rows = browser.find_elements(By.CSS_SELECTOR, "#browser-table tbody tr")
    assert len(rows) == 8  # 4 cases x 2 seeds
    overall = [float(r.find_elements(By.TAG_NAME, "td")[5].text) for r in rows]
    assert overall == sorted(overall)  # worst first
    rows[0].click()
    _wait(browser, "window.packlabReport.panes['pane-a'].m === 1")
    browser.find_element(By.ID, "pane-a-slider").send_keys(Keys.HOME, Keys.ARROW_RIGHT)
    _wait(browser, "document.getElementById('pane-a-step').textContent.indexOf('step 2 /') === 0")
    status = browser.find_element(By.ID, "pane-a-status")
    assert "invalid (out_of_bounds)" in status.text and "set aside" in status.text
    assert "invalid" in status.get_attribute("class")
    assert browser.find_elements(By.CSS_SELECTOR, "#pane-a .strip div.invalid")
    _replay_shot(browser, _shots(tmp_path) / "report_replay_invalid.png")
    assert (
        _severe(browser) == []
        and browser.execute_script("return window.packlabReport.errors") == []
    )


def _replay_shot(browser, path: Path) -> None:
    section = browser.find_element(By.ID, "replay")
    browser.execute_script("arguments[0].scrollIntoView()", section)
    time.sleep(0.3)  # let WebGL finish the frame
    section.screenshot(str(path))
    assert path.stat().st_size > 10_000


#: The default bench's 11 rows as the page names them (long names make the widest table).
DEFAULT_ROWS = (
    ("dblf", "DBLF"), ("hm", "HM"), ("mta", "MTA"), ("ffp", "FFP"), ("sdf", "SDF-Pack"),
    ("plan-fast", "Plan (completion + lookahead, fast)"), ("vlm", "PackLab pointer LM"),
    ("irbpp", "IR-BPP"), ("tapnet", "TAP-Net"), ("random", "Random"),
    ("oracle", "Oracle (gt plan)"),
)  # fmt: skip


def _eleven_rows(data: dict, tmp_path: Path) -> Path:
    """The small run's page with its DBLF row cloned into the default 11 rows (means shifted so
    each row differs), every cell with its interval."""
    import copy

    from packlab.viz.report_html import render_report_html

    wide = copy.deepcopy(data)
    base = data["methods"][0]
    wide["methods"] = []
    for k, (policy, name) in enumerate(DEFAULT_ROWS):
        row = copy.deepcopy(base)
        row.update(policy=policy, name=name)
        row["cells"] = [
            None if c is None else [c[0] * (0.5 + k / 20), *c[1:]] for c in row["cells"]
        ]
        wide["methods"].append(row)
    wide["replay"] = [5, 4]
    path = tmp_path / "eleven.html"
    path.write_text(render_report_html(wide, "2026-01-01 00:00:00 UTC"), encoding="utf-8")
    return path


#: Every header cell of the results table: text, colspan, data-group, left and right (px).
_HEADER_CELLS = """
return Array.from(document.querySelectorAll('#results-table thead th')).map(function (th) {
  var r = th.getBoundingClientRect();
  return {text: th.textContent, span: th.colSpan, group: th.getAttribute('data-group'),
          top: th.classList.contains('group'), left: r.left, right: r.right};
});
"""


def test_average_overall_is_on_screen_at_1400_px_and_levels_span_their_columns(
    report, browser, tmp_path
):
    """The default 11 rows at a 1400 px window: the Average Overall header's right edge is in
    the viewport without scrolling; each level header spans exactly its sub-columns."""
    _, data = report
    browser.get(_eleven_rows(data, tmp_path).as_uri())
    _wait(browser, "window.packlabReport && window.packlabReport.ready")
    assert browser.execute_script("return window.packlabReport.errors") == []
    assert browser.execute_script("return window.innerWidth") == 1400
    # Nothing scrolled: the page and the table's own scroll box are at their left edge.
    assert browser.execute_script(
        "return [window.scrollX, document.querySelector('#results .scroll').scrollLeft]"
    ) == [0, 0]
    viewport = browser.execute_script("return document.documentElement.clientWidth")
    headline = browser.find_element(By.ID, "results-headline")
    right = browser.execute_script("return arguments[0].getBoundingClientRect().right", headline)
    assert 0 < right <= viewport
    group = browser.execute_script(
        "return document.querySelector('#results-table th.group').textContent"
    )
    assert (group, headline.text) == ("Average", "Overall")  # Average's first column

    cells = browser.execute_script(_HEADER_CELLS)
    tops = [c for c in cells if c["top"]]
    subs = [c for c in cells if c["group"] and not c["top"]]
    assert [t["text"] for t in tops] == ["Average", "Easy", "Hard"]  # the tiny suite's levels
    for top in tops:
        mine = [c for c in subs if c["group"] == top["group"]]
        assert top["span"] == len(mine) == len(data["metrics"])
        assert top["left"] <= min(c["left"] for c in mine) + 0.5
        assert top["right"] >= max(c["right"] for c in mine) - 0.5
        others = [c for c in subs if c["group"] != top["group"]]
        assert all(
            c["right"] <= top["left"] + 0.5 or c["left"] >= top["right"] - 0.5 for c in others
        )
    # Rows best first by Average Overall, the oracle last.
    names = browser.execute_script(
        "return Array.from(document.querySelectorAll('#results-table tbody tr'))"
        ".map(r => r.cells[0].textContent)"
    )
    assert names[-1] == "Oracle (gt plan)" and names[0] == "Random"
    # Only Average Overall shows its interval until asked; the toggle shows every cell's.
    shown = "document.querySelectorAll('#results-table tbody td .sd').length && " \
        "Array.from(document.querySelectorAll('#results-table tbody td .sd'))" \
        ".filter(s => s.offsetParent !== null).length"  # fmt: skip
    assert browser.execute_script(f"return {shown}") == len(DEFAULT_ROWS)
    browser.find_element(By.ID, "t-intervals").click()
    n_cells = len(DEFAULT_ROWS) * len(data["groups"]) * len(data["metrics"])
    assert browser.execute_script(f"return {shown}") == n_cells
    # The replay opens on the rows the data name (the best method, the best heuristic).
    assert browser.execute_script(
        "return [window.packlabReport.panes['pane-a'].m, window.packlabReport.panes['pane-b'].m]"
    ) == [5, 4]
    browser.find_element(By.ID, "results").screenshot(
        str(_shots(tmp_path) / "report_results_11.png")
    )
    assert _severe(browser) == []
