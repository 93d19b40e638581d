"""Screenshots of a report.html in headless Chromium (the pictures in docs/report.md).

Usage:
    python scripts/report_screenshots.py RUN/report.html --out docs/img/report \\
        [--case bench-hard-00006 --left sdf --right dblf --step 12]

Writes OUT/report_header.png (the page's top: title and headline line), report_results.png
(the tables), report_boxes.png, report_cases.png (the case browser), report_replay.png (the
replay opened on the final packing of --case, default the page's own pick: its typical hard
case, the best method against the best heuristic) and report_replay_step<N>.png (the same at
step N with the buffer drawn in 3D).
Needs the test extra (selenium) and Debian's chromium + chromium-driver; no display.
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By

#: As the browser test: WebGL without a GPU, no sandbox (root), a fixed window 1400 px wide (the
#: width at which the tests check that the results table's headline column is on screen).
CHROME_ARGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-dev-shm-usage",
    "--enable-unsafe-swiftshader",
    "--window-size=1400,1100",
)
SETTLE_S = 0.8  # let the software rasteriser finish a WebGL frame


def _driver() -> webdriver.Chrome:
    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or "chromium"
    for arg in CHROME_ARGS:
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(options=options, service=Service(shutil.which("chromedriver")))


def _wait(driver: webdriver.Chrome, script: str, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if driver.execute_script(f"return {script}"):
            return
        time.sleep(0.1)
    raise TimeoutError(script)


def _shot(driver: webdriver.Chrome, element_id: str, path: Path, by: str = By.ID) -> Path:
    element = driver.find_element(by, element_id)
    driver.execute_script("arguments[0].scrollIntoView()", element)
    time.sleep(SETTLE_S)
    element.screenshot(str(path))
    return path


def screenshots(page: Path, out: Path, args: argparse.Namespace) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    driver = _driver()
    try:
        driver.get(page.resolve().as_uri())
        _wait(driver, "window.packlabReport && window.packlabReport.ready")
        written = [
            _shot(driver, "header", out / "report_header.png", By.TAG_NAME),
            _shot(driver, "results", out / "report_results.png"),
            _shot(driver, "boxes", out / "report_boxes.png"),
            _shot(driver, "browser", out / "report_cases.png"),
        ]
        if args.case:
            driver.execute_script(
                "window.packlabReport.done = false;"
                "window.packlabReport.open(arguments[0], arguments[1], arguments[2], arguments[3])"
                ".then(function () { window.packlabReport.done = true; });",
                args.case,
                args.seed,
                args.left,
                args.right,
            )
            _wait(driver, "window.packlabReport.done")
        written.append(_shot(driver, "replay", out / "report_replay.png"))
        if args.step:
            for pane in ("pane-a", "pane-b"):
                driver.find_element(By.ID, f"{pane}-buffer3d").click()
            driver.execute_script(
                "window.packlabReport.panes['pane-a'].setStep(arguments[0], true)", args.step
            )
            written.append(_shot(driver, "replay", out / f"report_replay_step{args.step}.png"))
        severe = [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        if severe:
            raise RuntimeError(f"console errors: {severe}")
    finally:
        driver.quit()
    return written


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("page", type=Path, help="a report.html")
    parser.add_argument("--out", type=Path, default=Path("docs/img/report"))
    parser.add_argument("--case", help="case id of the replay (default: the page's pick)")
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--left", help="method of the left pane (policy or row name)")
    parser.add_argument("--right", help="method of the right pane")
    parser.add_argument("--step", type=int, help="also a screenshot at this step, buffer in 3D")
    args = parser.parse_args()
    for path in screenshots(args.page, args.out, args):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
