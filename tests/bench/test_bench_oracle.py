"""The ceiling row: the oracle reaches Overall >= 0.99 on every bundled case with MuJoCo."""

from __future__ import annotations

import pytest

from packlab.bench.suites import load_suite
from packlab.bench.task import run_task


@pytest.mark.physics
def test_oracle_reaches_the_ceiling_on_every_bundled_case():
    low = []
    for case in load_suite():
        rec = run_task(case, "oracle", 0, "mujoco")
        assert rec.status == "ok", getattr(rec, "error", "")
        if rec.metrics.overall < 0.99:
            low.append((case.episode_id, round(rec.metrics.overall, 4)))
    assert not low, f"oracle below 0.99 on {low}"
