"""PackLab-Bench: frozen suites, a resumable runner, and reports rebuilt from records.

- :mod:`.suites`: bundled case files with checksums (``packlab-bench-v1``), any case file too.
- :mod:`.describe`: a suite's statistics per difficulty (``packlab bench --describe``).
- :mod:`.config`: ``RunConfig`` (what to run) and its resolved form saved as config.json.
- :mod:`.task`: one episode -> one record (run by ``packlab.executors``: in-process, pool or Ray).
- :mod:`.records`: episodes.jsonl of typed, versioned records (``packlab.core.records``): append,
  resume, torn-tail repair.
- :mod:`.runner`: ``run_bench``, the ``packlab bench`` entry point.
- :mod:`.summary` / :mod:`.table` / :mod:`.report`: records -> numbers -> Table 2 and figures.
- :mod:`.replay`: recorded actions -> step heightmaps (for ``packlab viz episode``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from packlab.core.lazy import lazy_attributes

if TYPE_CHECKING:
    from packlab.bench.config import ResolvedRun, RunConfig, resolve
    from packlab.bench.report import build_report
    from packlab.bench.runner import BenchOutcome, run_bench
    from packlab.bench.suites import (
        DEFAULT_SUITE,
        SUITES,
        SuiteIntegrityError,
        load_suite,
        resolve_cases,
    )
    from packlab.bench.summary import summarize

#: Where each name below lives. They are imported on first use (PEP 562), so importing one light
#: submodule (``packlab.bench.options``, for ``packlab bench --help``) loads no engine.
_HOMES = {
    "DEFAULT_SUITE": "packlab.bench.options",
    "SUITES": "packlab.bench.suites",
    "BenchOutcome": "packlab.bench.runner",
    "ResolvedRun": "packlab.bench.config",
    "RunConfig": "packlab.bench.options",
    "SuiteIntegrityError": "packlab.bench.suites",
    "build_report": "packlab.bench.report",
    "load_suite": "packlab.bench.suites",
    "resolve": "packlab.bench.config",
    "resolve_cases": "packlab.bench.suites",
    "run_bench": "packlab.bench.runner",
    "summarize": "packlab.bench.summary",
}

__getattr__ = lazy_attributes(__name__, _HOMES)


__all__ = [
    "DEFAULT_SUITE",
    "SUITES",
    "BenchOutcome",
    "ResolvedRun",
    "RunConfig",
    "SuiteIntegrityError",
    "build_report",
    "load_suite",
    "resolve",
    "resolve_cases",
    "run_bench",
    "summarize",
]
