"""mypy over src/packlab with the project's configuration ([tool.mypy] in pyproject.toml): no
errors, the public API strict (docs/typing.md)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_mypy_reports_no_errors() -> None:
    # As a developer runs it: `mypy` in the repository root reads files and flags from
    # pyproject.toml (its cache, .mypy_cache/, makes a rerun take a second or two).
    run = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml")],
        check=False,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    errors = [line for line in run.stdout.splitlines() if ": error:" in line]
    if run.returncode != 0 or errors:
        pytest.fail(
            f"mypy exited {run.returncode} with {len(errors)} errors:\n"
            + "\n".join(errors or run.stdout.splitlines()[-20:])
            + (f"\n{run.stderr}" if run.stderr else ""),
            pytrace=False,
        )


def test_the_package_ships_its_types() -> None:
    assert (ROOT / "src" / "packlab" / "py.typed").is_file()
