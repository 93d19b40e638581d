"""The report page's results table in headless Chromium: a cell shows ``mean [low, high]`` (the
95 % bootstrap interval) when the page's data carry the bounds, and the old ``mean ± sd`` for a
page whose cells are only [mean, std] (data made before intervals). Skipped as
test_report_browser.py is, where no Chromium / chromedriver / selenium is found."""

from __future__ import annotations

import copy

import pytest
from test_report_browser import _severe, _wait, browser, report  # noqa: F401 (fixtures)

from packlab.viz.report_html import render_report_html

pytestmark = pytest.mark.browser


def _shown_order(data: dict) -> list[int]:
    """Indices into a method's cells in the page's column order: the average first (the
    headline group), then the levels; Overall first in each group."""
    n_metrics = len(data["metrics"])
    groups = list(range(len(data["groups"])))
    if len(groups) > 1:
        groups = [groups[-1], *groups[:-1]]
    overall = [m[0] for m in data["metrics"]].index("overall")
    metrics = [overall, *(i for i in range(n_metrics) if i != overall)]
    return [g * n_metrics + m for g in groups for m in metrics]


def _cell_texts(driver) -> list[list[str]]:
    """The results table's cells as shown, the method column left out."""
    return driver.execute_script(
        "return Array.from(document.querySelectorAll('#results-table tbody tr')).map("
        "r => Array.from(r.querySelectorAll('td')).slice(1).map(td => td.textContent))"
    )


def _caption(driver) -> str:
    return driver.execute_script("return document.querySelector('#results > p.muted').textContent")


def _open(driver, path) -> None:
    driver.get(path.as_uri())
    _wait(driver, "window.packlabReport && window.packlabReport.ready")
    assert driver.execute_script("return window.packlabReport.errors") == []
    assert _severe(driver) == []


def test_cells_show_the_bootstrap_interval(report, browser):  # noqa: F811
    path, data = report
    _open(browser, path)
    order = _shown_order(data)
    wanted = [
        ["-" if c is None or c[0] is None else f"{c[0]:.3f} [{c[2]:.3f}, {c[3]:.3f}]"
         for c in (m["cells"][i] for i in order)]
        for m in data["methods"]  # DBLF scores above test-sloppy: the ranked order is theirs
    ]  # fmt: skip
    assert all(len(c) == 4 and c[2] is not None for m in data["methods"] for c in m["cells"])
    assert _cell_texts(browser) == wanted
    assert "95 % bootstrap interval over cases" in _caption(browser)


def test_cells_without_bounds_keep_the_old_sd_form(report, browser, tmp_path):  # noqa: F811
    _, data = report
    old = copy.deepcopy(data)
    for m in old["methods"]:
        m["cells"] = [None if c is None else c[:2] for c in m["cells"]]
    old["methods"][0]["cells"][-1] = [*data["methods"][0]["cells"][-1][:2], None, None]
    path = tmp_path / "old.html"
    path.write_text(render_report_html(old, "2026-01-01 00:00:00 UTC"), encoding="utf-8")
    _open(browser, path)
    wanted = [
        ["-" if c is None or c[0] is None else f"{c[0]:.3f} ± {c[1] or 0:.3f}"
         for c in (m["cells"][i] for i in _shown_order(old))]
        for m in old["methods"]
    ]  # fmt: skip
    assert _cell_texts(browser) == wanted
    assert "sample std across seeds" in _caption(browser)
    assert "bootstrap" not in _caption(browser)
