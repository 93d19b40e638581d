"""The planning step needs the core install only: a driver that holds its images as arrays
(a bench adapter) calls ``packlab.cell.step`` without the cell extra, and ``packlab cell
--help`` works without it too."""

from __future__ import annotations

import json
import subprocess
import sys

EXTRA = ("fastapi", "starlette", "uvicorn", "httpx", "pydantic")
PROBE = """
import json, sys
import packlab.cell.step, packlab.cell.geometry, packlab.cell.buffer, packlab.cell.images
import packlab.cell.settings, packlab.cli.cell
print(json.dumps(sorted(sys.modules)))
"""


def test_the_step_imports_nothing_of_the_extra():
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, check=True)
    loaded = json.loads(done.stdout.splitlines()[-1])
    assert [m for m in loaded if m.split(".")[0] in EXTRA] == []
