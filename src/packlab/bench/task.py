"""One unit of bench work: a (case, policy, run seed) episode turned into a record.

This is what workers execute. It never raises for a policy or engine failure: the failure is
the record (``status: "error"`` with the traceback), so one crashing policy on one case cannot
stop a run of thousands of episodes.
"""

from __future__ import annotations

import os
import time
import traceback
from dataclasses import dataclass
from typing import Any

from packlab.policies import make_policy
from packlab.sim.episode import run_episode
from packlab.types import Case


@dataclass(frozen=True, slots=True)
class Task:
    """An episode to run: the case by index into the run's case list (cheap to send to workers)."""

    case_index: int
    policy: str
    seed: int


def _header(case: Case, policy: str, seed: int, backend: str) -> dict[str, Any]:
    # Key fields first so a record reads well in a text editor.
    return {
        "case_id": case.episode_id,
        "seed": seed,
        "policy": policy,
        "backend": backend,
        "difficulty": case.difficulty,
        "n_objects": len(case.objects),
    }


def run_task(case: Case, policy: str, seed: int, backend: str, physics: Any = None,
             policy_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """The record of one episode (``status`` "ok"), or of its failure (``status`` "error").

    A fresh policy per episode (``make_policy(policy, **policy_kwargs)``), so no state leaks
    between episodes; policies that hold heavy models cache them per process themselves.
    """
    started, started_cpu = time.perf_counter(), time.process_time()
    head = _header(case, policy, seed, backend)
    try:
        result = run_episode(case, make_policy(policy, **(policy_kwargs or {})), seed, backend=backend, physics=physics)
        body = result.to_record()
        # The registry name is the key (a policy object's own ``name`` could differ).
        body["policy"] = policy
        record = {"status": "ok", **head, **body}
        step_s = sum(s.wall_time_s for s in result.steps)
        timing = {"policy_s": round(result.policy_time_s, 6), "env_s": round(step_s, 6),
                  "decisions": len(result.steps)}
    except Exception as exc:  # noqa: BLE001 - any failure of a policy or engine is data here
        message = " ".join(f"{type(exc).__name__}: {exc}".split())  # one line
        record = {"status": "error", **head, "error": message[:500], "traceback": traceback.format_exc()}
        timing = {}
    # cpu_s beside the wall time: on a shared machine the wall time also counts time spent
    # waiting for a core, the CPU time only the episode's own work.
    record["timing"] = {"episode_s": round(time.perf_counter() - started, 6),
                        "cpu_s": round(time.process_time() - started_cpu, 6), **timing, "pid": os.getpid()}
    return record


__all__ = ["Task", "run_task"]
