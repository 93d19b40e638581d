"""Small runs for the HTML report's tests: a few tiny cases on the geometric backend, with a
policy that also makes invalid and unparsable steps so the page has set-aside boxes to show."""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from packlab.bench.config import RunConfig
from packlab.bench.runner import BenchOutcome, run_bench
from packlab.core.records import RUN_FORMAT_1
from packlab.core.types import Action, Case, Observation, Unparsable
from packlab.policies import make_policy
from packlab.policies.registry import _RUNTIME as _FACTORIES
from packlab.policies.registry import register_policy

SLOPPY = "test-sloppy"


class Sloppy:
    """DBLF, except that its 2nd decision is out of the container and its 4th does not parse."""

    name = SLOPPY

    def reset(self, case: Case, seed: int) -> None:
        self._inner = make_policy("dblf")
        self._inner.reset(case, seed)
        self._n = 0

    def act(self, observation: Observation) -> Action | Unparsable:
        self._n += 1
        if self._n == 2:
            return Action(0, 0, 10_000, 0)
        if self._n == 4:
            return Unparsable("the box goes <left>", "no JSON object found")
        return self._inner.act(observation)


@contextmanager
def sloppy_policy() -> Iterator[str]:
    """The sloppy policy registered for the duration (other tests never see it)."""
    register_policy(SLOPPY)(Sloppy)
    try:
        yield SLOPPY
    finally:
        _FACTORIES.pop(SLOPPY, None)


def small_run(
    cases: Path,
    out: Path,
    policies: Sequence[str] = ("dblf", SLOPPY),
    seeds: Sequence[int] = (0, 1),
) -> BenchOutcome:
    """A run in this process (workers=1, so test-registered policies are seen), no outputs but
    the records, summary and table."""
    config = RunConfig(
        cases=str(cases),
        out=str(out),
        backend="geometric",
        policies=tuple(policies),
        seeds=tuple(seeds),
        workers=1,
        progress=False,
    )
    return run_bench(config, figures=False, html=False)


def rewrite_records(run_dir: Path, change) -> None:
    """Apply ``change(record dict)`` to every line of a run's episodes.jsonl."""
    path = run_dir / "episodes.jsonl"
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    for rec in lines:
        change(rec)
    path.write_text("".join(json.dumps(r, separators=(",", ":")) + "\n" for r in lines))


def _record_as_run1(rec: dict) -> None:
    del rec["format"]
    m = rec["metrics"]
    m["capped_placements"] = m.pop("unsettled_steps")
    for key in ("final_settle_steps", "at_rest", "residual_linear_mps", "residual_angular_radps"):
        del m[key]
    for s in rec["steps"]:
        s["capped"] = not s.pop("settled")
        del s["max_linear_speed_mps"], s["max_angular_speed_radps"]
        s.pop("poses", None)


def as_run1(run_dir: Path) -> None:
    """Rewrite a run directory as packlab-bench-run-1 wrote it (config format 1; records without
    ``format``, steps ``capped`` and no poses, metrics ``capped_placements``, no rest fields)."""
    config = json.loads((run_dir / "config.json").read_text())
    (run_dir / "config.json").write_text(json.dumps({**config, "format": RUN_FORMAT_1}, indent=1))
    rewrite_records(run_dir, _record_as_run1)
