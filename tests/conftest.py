"""Shared fixtures (the case generator lives in layered_cases.py so tests can import it)."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest
from browser_note import pytest_terminal_summary  # noqa: F401  (a hook: one line when skipped)
from layered_cases import make_layered_case

from packlab.core.types import Case


@pytest.fixture
def layered_case() -> Case:
    return make_layered_case(1)


@pytest.fixture(scope="session")
def ray_cluster():
    """One local Ray cluster for every Ray test (starting one costs seconds; tests reuse it).

    The executors use an already-initialised Ray and leave it running. Ray workers are fresh
    processes: they import the tests' helper modules from these directories, and the setup hook
    registers the bench fault-test policies in each of them.
    """
    ray = pytest.importorskip("ray")
    # Ray's log handlers keep the stream that was sys.stderr when they were made, which is
    # pytest's capture of one test; writing to it after that test printed "--- Logging error ---"
    # and a traceback among the dots. A handler's I/O error is not a test failure: stay quiet.
    logging.raiseExceptions = False
    tests = Path(__file__).parent
    path = os.pathsep.join([str(tests), str(tests / "bench"), os.environ.get("PYTHONPATH", "")])
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        runtime_env={
            "env_vars": {"PYTHONPATH": path},
            "worker_process_setup_hook": "fault_policies.register_all",
        },
    )
    yield ray
    ray.shutdown()
