"""Fixtures of the cell service's tests: the app over sessions in this process, its client,
and steps rendered by packlab's simulated cameras (cell_scenes.py).

Without the cell extra only the core-install test is collected: the others need FastAPI,
uvicorn and httpx.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

EXTRA = ("fastapi", "uvicorn", "httpx", "pydantic")

if any(importlib.util.find_spec(m) is None for m in EXTRA):
    collect_ignore = [
        p.name
        for p in Path(__file__).parent.glob("test_*.py")
        if p.name != "test_cell_core_install.py"
    ]


@pytest.fixture
def sessions():
    from packlab.cell.sessions import LocalSessions

    return LocalSessions("plan-fast", max_sessions=32)


@pytest.fixture
def http(sessions):
    from fastapi.testclient import TestClient

    from packlab.cell.app import create_app

    # raise_server_exceptions=False: a 500 comes back as a response, as a cell would see it.
    with TestClient(create_app(sessions, "plan-fast"), raise_server_exceptions=False) as client:
        yield client


@pytest.fixture
def client(http):
    from packlab.cell.client import CellClient

    return CellClient(client=http)


@pytest.fixture(scope="module")
def medium_case():
    from cell_scenes import generated_case

    return generated_case("medium", seed=5)


@pytest.fixture(scope="module")
def medium_scenes(medium_case):
    from cell_scenes import PRESET

    from packlab.cell.simulated import planned_steps

    return planned_steps(medium_case, PRESET, steps=4, seed=1)
