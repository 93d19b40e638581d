"""One line at the end of a test run when the browser tests were skipped.

The tests marked ``browser`` drive a real headless Chromium and skip themselves where Chromium,
chromedriver or selenium is missing. ``.ci/run`` installs them; README's test command cannot
(apt needs root), so without this note a newcomer's run would drop them without a word.
tests/conftest.py installs :func:`pytest_terminal_summary` as its hook.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

#: How to get the browser tests to run, in the words of README's Tests section.
ENABLE = (
    "to run them: apt-get install chromium chromium-driver (Debian/Ubuntu, as root; .ci/run "
    "does this), or point PACKLAB_CHROMIUM and PACKLAB_CHROMEDRIVER at a Chromium and its driver"
)
#: A test module whose tests are all browser tests says so with ``pytestmark``; a module that
#: skips itself at import time reports no markers, so its source is what tells.
MODULE_MARK = re.compile(r"pytestmark\s*=.*\bmark\.browser\b")


def _reason(report: Any) -> str:
    longrepr = report.longrepr
    text = longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else str(longrepr)
    return text.removeprefix("Skipped: ").strip()


def _is_browser(report: Any, root: Path) -> bool:
    if "browser" in getattr(report, "keywords", {}):
        return True  # a test item that carries the marker
    if report.when != "collect":  # (CollectReport.when is "collect")
        return False
    module = root / report.nodeid.split("::")[0]
    if module.suffix != ".py" or not module.is_file():
        return False
    return bool(MODULE_MARK.search(module.read_text(encoding="utf-8")))


def browser_note(skipped: list[Any], root: Path, markexpr: str = "") -> str | None:
    """The line for the skipped reports ``skipped`` (``None``: no browser test was skipped, or
    the run asked for none with ``-m "not browser"``)."""
    if re.search(r"\bnot\s+browser\b", markexpr):
        return None
    found = [r for r in skipped if _is_browser(r, root)]
    if not found:
        return None
    modules = {r.nodeid for r in found if r.when == "collect"}
    tests = {r.nodeid for r in found if r.when != "collect"}
    counts = [
        f"{n} {noun}{'s' if n != 1 else ''}"
        for n, noun in ((len(modules), "module"), (len(tests), "test"))
        if n
    ]
    reasons = "; ".join(sorted({_reason(r) for r in found}))
    return f"browser tests skipped ({', '.join(counts)}): {reasons}; {ENABLE}."


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: Any) -> None:
    line = browser_note(
        terminalreporter.stats.get("skipped", []),
        Path(config.rootpath),
        config.getoption("markexpr", "") or "",
    )
    if line:
        terminalreporter.write_line(line, yellow=True, bold=True)
