"""Records -> the numbers of a bench run (pure; the runner and the report both call this).

Aggregation, chosen to match the paper's Table 2 and stated here once:

* A case's score for one seed is that episode's metric (Overall per episode = SR x C, so the
  table's Overall is the mean of per-episode products, not the product of the means).
* A difficulty's score for one seed is the mean over its cases; ``average`` is the mean of the
  difficulty scores (equal weight per difficulty; with equal case counts, the mean over cases).
* Each cell reports the mean over seeds of those per-seed scores and their spread: the sample
  standard deviation across seeds (0 with a single seed).
* Settling (physics backends): ``counts`` has per method the placements whose settle hit the
  per-placement cap (``unsettled_steps``), the episodes scored while boxes still moved because
  the final settle hit its cap (``not_at_rest``; such episodes stay in the means), and the
  largest residual speeds at scoring.
* Failed episodes (``status: "error"``) are left out of the means and counted in ``counts`` and
  ``errors``; the table flags a method with failures, since its mean covers fewer episodes.

Records are sorted by key before any sum, so the result does not depend on the order in which
parallel workers finished, and the summary of records read back from disk equals the live one.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Sequence
from typing import Any

from packlab.bench.describe import difficulty_order
from packlab.bench.records import record_key
from packlab.metrics import AVERAGE, METRICS


def _mean(values: Sequence[float]) -> float:
    return math.fsum(values) / len(values) if values else float("nan")


def _std(values: Sequence[float]) -> float:
    """Sample standard deviation (n - 1); 0 for fewer than two values."""
    if len(values) < 2:
        return 0.0
    m = _mean(values)
    return math.sqrt(math.fsum((v - m) ** 2 for v in values) / (len(values) - 1))


def _cell(per_seed: dict[str, float]) -> dict[str, Any]:
    values = list(per_seed.values())
    return {"mean": _mean(values), "std": _std(values), "per_seed": per_seed}


def _nan_to_none(obj: Any) -> Any:
    """JSON has no NaN; a missing mean (no finished episode) is written as null."""
    if isinstance(obj, float) and math.isnan(obj):
        return None
    if isinstance(obj, dict):
        return {k: _nan_to_none(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_nan_to_none(v) for v in obj]
    return obj


def _unsettled_steps(metrics: dict[str, Any]) -> int:
    """Placements whose settle hit its cap; records written before ``unsettled_steps`` named
    the same count ``capped_placements``."""
    return int(metrics.get("unsettled_steps", metrics.get("capped_placements", 0)))


def summarize(records: Iterable[dict[str, Any]], policies: Sequence[str] | None = None,
              seeds: Sequence[int] | None = None, difficulties: Sequence[str] | None = None,
              meta: dict[str, Any] | None = None) -> dict[str, Any]:
    """The summary (JSON-able) of a run's records; see the module docstring for the rules.

    ``policies`` / ``seeds`` / ``difficulties`` fix the order (and selection) of rows and
    columns; by default they are taken from the records.
    """
    recs = sorted(records, key=record_key)
    if policies is None:
        policies = list(dict.fromkeys(r["policy"] for r in recs))
    if seeds is None:
        seeds = sorted({int(r["seed"]) for r in recs})
    if difficulties is None:
        difficulties = difficulty_order([r.get("difficulty", "") for r in recs])
    policies, seeds, difficulties = list(policies), [int(s) for s in seeds], list(difficulties)
    wanted = set(policies)
    recs = [r for r in recs if r["policy"] in wanted and int(r["seed"]) in seeds
            and r.get("difficulty", "") in difficulties]
    ok = [r for r in recs if r.get("status", "ok") == "ok"]
    errors = [r for r in recs if r.get("status", "ok") != "ok"]

    # metric value by (policy, difficulty, case, seed)
    value: dict[tuple[str, str], dict[str, dict[int, dict[str, float]]]] = defaultdict(lambda: defaultdict(dict))
    for r in ok:
        value[(r["policy"], r.get("difficulty", ""))][r["case_id"]][int(r["seed"])] = {
            m: float(r["metrics"][m]) for m in METRICS
        }

    table: dict[str, dict[str, dict[str, Any]]] = {}
    per_case: dict[str, dict[str, Any]] = {}
    for p in policies:
        table[p], per_case[p] = {}, {}
        by_group: dict[str, dict[str, dict[str, float]]] = {}  # group -> metric -> seed -> score
        for d in difficulties:
            cases = value.get((p, d), {})
            by_group[d] = {}
            for m in METRICS:
                by_group[d][m] = {}
                for s in seeds:
                    scores = [cases[c][s][m] for c in sorted(cases) if s in cases[c]]
                    if scores:
                        by_group[d][m][str(s)] = _mean(scores)
            for c in sorted(cases):
                per_case[p][c] = {"difficulty": d, **{
                    m: _cell({str(s): cases[c][s][m] for s in seeds if s in cases[c]}) for m in METRICS}}
        by_group[AVERAGE] = {}
        for m in METRICS:
            by_group[AVERAGE][m] = {}
            for s in seeds:
                parts = [by_group[d][m][str(s)] for d in difficulties if str(s) in by_group[d][m]]
                if len(parts) == len(difficulties) and parts:
                    by_group[AVERAGE][m][str(s)] = _mean(parts)
        for g, metrics in by_group.items():
            table[p][g] = {m: _cell(per_seed) for m, per_seed in metrics.items()}

    counts: dict[str, dict[str, Any]] = {}
    for p in policies:
        mine = [r for r in ok if r["policy"] == p]
        steps = [s for r in mine for s in r.get("steps", ())]
        decisions = sum(r.get("timing", {}).get("decisions", 0) for r in mine)
        policy_s = math.fsum(r.get("timing", {}).get("policy_s", 0.0) for r in mine)
        env_s = math.fsum(r.get("timing", {}).get("env_s", 0.0) for r in mine)
        counts[p] = {
            "episodes": len(mine),
            "errors": sum(1 for r in errors if r["policy"] == p),
            "steps": len(steps),
            "invalid_steps": sum(1 for s in steps if not s.get("valid", True)),
            "set_aside": sum(int(r["metrics"].get("n_set_aside", 0)) for r in mine),
            "unsettled_steps": sum(_unsettled_steps(r["metrics"]) for r in mine),
            "not_at_rest": sum(1 for r in mine if r["metrics"].get("at_rest") is False),
            "max_residual_linear_mps": max((float(r["metrics"].get("residual_linear_mps", 0.0)) for r in mine),
                                           default=0.0),
            "max_residual_angular_radps": max((float(r["metrics"].get("residual_angular_radps", 0.0))
                                               for r in mine), default=0.0),
            "decision_ms": 1000.0 * policy_s / decisions if decisions else float("nan"),
            "step_ms": 1000.0 * env_s / decisions if decisions else float("nan"),
            "episode_s": _mean([r.get("timing", {}).get("episode_s", 0.0) for r in mine]),
        }

    summary = {
        **(meta or {}),
        "policies": policies,
        "seeds": seeds,
        "difficulties": difficulties,
        "metrics": list(METRICS),
        "aggregation": "per-seed mean over cases (average: mean of difficulties); mean and sample std over seeds",
        "table": table,
        "per_case": per_case,
        "counts": counts,
        "errors": [{"case_id": r["case_id"], "seed": r["seed"], "policy": r["policy"],
                    "error": r.get("error", "")} for r in errors],
    }
    return _nan_to_none(summary)


__all__ = ["AVERAGE", "METRICS", "summarize"]
