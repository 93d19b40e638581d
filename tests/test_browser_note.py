"""The one line a test run ends with when browser tests were skipped (tests/browser_note.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

from browser_note import ENABLE, browser_note

TESTS = Path(__file__).resolve().parent

CONFTEST = """
from browser_note import pytest_terminal_summary

def pytest_configure(config):
    config.addinivalue_line("markers", "browser: drives a real browser")
"""
MODULE_SKIP = """
import pytest
pytestmark = pytest.mark.browser
pytest.skip("no chromium / chromedriver", allow_module_level=True)
"""
ITEM_SKIP = """
import pytest

@pytest.mark.browser
def test_page():
    pytest.skip("no selenium")

def test_other():
    pytest.skip("unrelated")
"""
PLAIN_SKIP = """
import pytest

def test_plain():
    pytest.skip("no chromium here either, but not a browser test")
"""


def run_pytest(tmp_path: Path, files: dict[str, str], *args: str) -> list[str]:
    """Run pytest on a small project of ``files``; its output lines."""
    for name, text in {"conftest.py": CONFTEST, **files}.items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    (tmp_path / "pytest.ini").write_text("[pytest]\n", encoding="utf-8")
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-q", *args],
        cwd=tmp_path,
        check=False,
        env={"PYTHONPATH": str(TESTS), "PATH": ""},
        capture_output=True,
        text=True,
        timeout=120,
    )
    # 5: pytest collected nothing to run (every module skipped or left out by -m)
    assert done.returncode in (0, 5), done.stdout + done.stderr
    return done.stdout.splitlines()


def notes(lines: list[str]) -> list[str]:
    return [line for line in lines if line.startswith("browser tests skipped")]


def test_skipped_browser_tests_get_one_line_with_why_and_how(tmp_path):
    lines = run_pytest(tmp_path, {"test_module.py": MODULE_SKIP, "test_items.py": ITEM_SKIP})
    (note,) = notes(lines)
    assert note.startswith("browser tests skipped (1 module, 1 test): ")
    assert "no chromium / chromedriver" in note and "no selenium" in note
    assert "unrelated" not in note  # a skip without the marker is not a browser test
    assert "apt-get install chromium chromium-driver" in note and "PACKLAB_CHROMIUM" in note


def test_no_line_without_skipped_browser_tests(tmp_path):
    assert notes(run_pytest(tmp_path, {"test_plain.py": PLAIN_SKIP})) == []


def test_no_line_when_the_run_leaves_browser_tests_out(tmp_path):
    lines = run_pytest(tmp_path, {"test_module.py": MODULE_SKIP}, "-m", "not browser")
    assert notes(lines) == []


def test_the_real_browser_module_is_recognised():
    """The report's browser tests skip at import; their module's marker is what names them."""
    module = "tests/bench/test_report_browser.py"
    report = SimpleNamespace(
        nodeid=module, when="collect", keywords={}, longrepr=(module, 1, "Skipped: no chromium")
    )
    assert browser_note([report], TESTS.parent) == (
        f"browser tests skipped (1 module): no chromium; {ENABLE}."
    )
