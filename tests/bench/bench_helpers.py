"""Small hand-made cases for the bench tests: exact two-layer tilings with a perfect plan.

Independent of the data engine on purpose, so runner, records and report tests do not change
when the generator does. Each layer of a (nx x ny)-cell container is cut into strips, so the
plan is valid in arrival order and the oracle scores 1 on the geometric backend.
"""

from __future__ import annotations

import json
from itertools import pairwise
from pathlib import Path

import numpy as np

from packlab.bench.config import RunConfig
from packlab.bench.runner import BenchOutcome, run_bench
from packlab.cases import save_cases
from packlab.core.types import Box, Case, Container, PlanStep

CELL = 25


def strip_case(
    seed: int,
    difficulty: str = "easy",
    nx: int = 8,
    ny: int = 6,
    layers=(100, 60),
    buffer_size: int = 3,
) -> Case:
    """Each layer is 2-3 strips along x of random widths; some objects arrive rotated."""
    rng = np.random.default_rng(seed)
    objects, plan, z = [], [], 0
    for layer, h in enumerate(layers):
        cuts = sorted(
            rng.choice(np.arange(2, nx - 1), size=int(rng.integers(1, 3)), replace=False).tolist()
        )
        edges = [0, *cuts, nx]
        for x0, x1 in pairwise(edges):
            dx = x1 - x0
            rotation = int(rng.random() < 0.3)
            size = (ny * CELL, dx * CELL, h) if rotation else (dx * CELL, ny * CELL, h)
            iid = len(objects)
            objects.append(Box(iid, size, gt_index=iid, type_id=iid % 5))
            plan.append(
                PlanStep(iid, iid, layer, (x0, 0, z // 2), (dx, ny, h // 2), x0, 0, rotation)
            )
        z += h
    container = Container((nx * CELL, ny * CELL, z + 40))
    return Case(
        f"{difficulty}-{seed}",
        container,
        buffer_size,
        tuple(objects),
        seed=seed,
        difficulty=difficulty,
        gt_plan=tuple(plan),
    )


def tiny_cases() -> list[Case]:
    """Four cases over two difficulties."""
    return [
        strip_case(1, "easy"),
        strip_case(2, "easy"),
        strip_case(3, "hard", nx=10, ny=8, layers=(80, 80, 60), buffer_size=4),
        strip_case(4, "hard", nx=10, ny=8, layers=(80, 80, 60), buffer_size=4),
    ]


def write_tiny_suite(directory: Path) -> Path:
    path = directory / "tiny.jsonl"
    save_cases(tiny_cases(), path)
    return path


def run_tiny(suite: Path, out: Path, **config) -> BenchOutcome:
    """A quick bench run of ``suite``: DBLF, seed 0, geometric, in this process, no figures or
    report.html; ``config`` overrides or adds RunConfig fields (modes, policies, ...)."""
    fields = {"backend": "geometric", "policies": ("dblf",), "seeds": (0,), "workers": 1}
    full = RunConfig(cases=str(suite), out=str(out), progress=False, **{**fields, **config})
    return run_bench(full, figures=False, html=False)


def oracle_records(cases: str, out: Path) -> list[dict]:
    """The oracle's episode records of a suite (or case file): seed 0, geometric, in this
    process, as JSON objects (a bundled suite's "1.0 is reachable" check)."""
    run_bench(
        RunConfig(
            cases=cases,
            policies=("oracle",),
            seeds=(0,),
            backend="geometric",
            out=str(out),
            workers=1,
            progress=False,
        ),
        figures=False,
        html=False,
    )
    with open(out / "episodes.jsonl", encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]
