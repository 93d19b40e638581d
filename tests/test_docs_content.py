"""The product's documentation is a user's guide: a short README, no development log, and a docs
site that builds with no warning.

History (what changed when, and the measured attempts that did not ship) belongs in
CHANGELOG.md and on the results-history pages; even there, a commit appears only on a stamp
line. These checks keep it that way.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 250

#: The words of a development log. A commit hash: 7 to 40 hex characters with a digit and a
#: letter in them (so words such as "decade" pass).
LOG_PATTERNS = {
    # A work session ("session 55", "this session"); an ONNX Runtime or HTTP session passes.
    "a session": re.compile(
        r"\bsessions?[- ]\d+|\b(this|last|previous|next|earlier|later|that|same|whole|"
        r"one|each|every) sessions?\b(?! (with|object|option))",
        re.IGNORECASE,
    ),
    "an issue number": re.compile(r"\bissues?[ -]?#?\d+", re.IGNORECASE),
    "a turn": re.compile(r"\bturns? \d+\b", re.IGNORECASE),
    "a commit hash": re.compile(r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b"),
    "a figure's history": re.compile(r"\d\.\d+\s*(->|→)\s*\d\.\d+"),
}

#: Stamp lines say which command, commit and date produced a table; they may name a commit.
STAMP = re.compile(r"^\s*(Stamp: |Produced by `python benchmarks/)")


def product_pages() -> list[Path]:
    pages = [ROOT / "README.md", ROOT / "CONTRIBUTING.md"]
    pages += sorted((ROOT / "docs").rglob("*.md"))
    pages += sorted((ROOT / "examples").rglob("*.md"))
    return [p for p in pages if p.is_file()]


def log_lines(path: Path) -> list[str]:
    found = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if STAMP.match(line):
            continue
        for what, pattern in LOG_PATTERNS.items():
            if pattern.search(line):
                name = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name
                found.append(f"{name}:{number}: {what}: {line.strip()[:120]}")
    return found


def test_the_readme_is_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, len(lines)


def test_no_development_log_in_the_product():
    found = [line for page in product_pages() for line in log_lines(page)]
    assert not found, "\n".join(found)


def test_the_log_patterns_catch_what_they_should(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "Measured in session 55.\nSee issue 36.\nNo GPU was lent to this session.\n"
        "Decisions (turn 4)\nat commit 618eb62\n"
        "0.952 -> 0.961\nA decade of boxes, 0.95 and 12.5 cm.\n"
        "Stamp: measured at commit 618eb62.\nAn ONNX Runtime session with two threads.\n",
        encoding="utf-8",
    )
    found = log_lines(page)
    assert len(found) == 6, found


def test_the_project_files_a_user_looks_for_exist():
    for name in ("LICENSE", "CHANGELOG.md", "CONTRIBUTING.md", "CITATION.cff", "examples"):
        assert (ROOT / name).exists(), name
    assert "Apache License" in (ROOT / "LICENSE").read_text(encoding="utf-8")


@pytest.mark.skipif(shutil.which("mkdocs") is None, reason="mkdocs not installed (docs extra)")
def test_the_docs_site_builds_strict_with_no_warning(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        check=False,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    output = done.stdout + done.stderr
    warnings = [line for line in output.splitlines() if "WARNING" in line]
    assert done.returncode == 0 and not warnings, output[-4000:]
    assert (tmp_path / "site" / "cli" / "index.html").is_file()


def test_the_cli_reference_is_read_from_the_parsers():
    from packlab.cli.reference import cli_reference_markdown

    text = cli_reference_markdown()
    for command in ("packlab bench", "packlab generate", "packlab train sft", "packlab policies"):
        assert f"`{command}`" in text, command
    assert "--policy-arg" in text


def test_no_development_log_in_the_code_text():
    """Comments, docstrings and help texts say what the code does and why, not when."""
    words = {k: LOG_PATTERNS[k] for k in ("a session", "an issue number", "a turn")}
    found = []
    for folder in ("src", "scripts", "benchmarks", "examples", "configs"):
        for path in sorted((ROOT / folder).rglob("*")):
            if path.suffix not in (".py", ".sh", ".js", ".yaml", ".toml") or not path.is_file():
                continue
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                found += [
                    f"{path.relative_to(ROOT)}:{number}: {what}: {line.strip()[:100]}"
                    for what, pattern in words.items()
                    if pattern.search(line)
                ]
    assert not found, "\n".join(found)
