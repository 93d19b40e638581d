"""Fixtures of the bench tests: a tiny case file and a policy that crashes on purpose."""

from __future__ import annotations

import pytest
from bench_helpers import write_tiny_suite

from packlab.core.types import Action, Case, Observation
from packlab.policies.registry import _RUNTIME as _FACTORIES
from packlab.policies.registry import register_policy

CRASH_POLICY = "test-crash"


class CrashOnHard:
    """Packs like FFP's dumbest cousin on easy cases; raises on the first step of a hard one."""

    name = CRASH_POLICY
    needs_case = True  # it reads the case's level, which no real policy is handed

    def reset(self, case: Case, seed: int) -> None:
        self._hard = case.difficulty == "hard"

    def act(self, observation: Observation) -> Action:
        if self._hard:
            raise RuntimeError("deliberate failure on a hard case")
        return Action(0, 0, 0, 0)


@pytest.fixture
def crash_policy():
    """Register the crashing policy for one test only (others must not see it in the registry)."""
    register_policy(CRASH_POLICY)(CrashOnHard)
    try:
        yield CRASH_POLICY
    finally:
        _FACTORIES.pop(CRASH_POLICY, None)


@pytest.fixture
def tiny_suite(tmp_path):
    return write_tiny_suite(tmp_path)
