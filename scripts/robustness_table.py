"""The robustness table of docs/perception.md from three bench runs of the same policies.

Usage: python scripts/robustness_table.py EXACT_RUN PERCEIVED_RUN NOISY_RUN [MORE_RUNS ...]

Each argument is a `packlab bench --out` directory (or several, comma-separated, whose policies
are merged: e.g. the slow planner run apart). The runs are, in order: exact observation and
execution, perceived observation, perceived observation and noisy execution (same suite,
backend, seeds and noise preset). Prints one markdown row per policy: average Overall (mean ±
std over seeds) in each mode, the loss from exact to perceived+noisy, and re-plans per episode;
then the perception errors over every shown object of every step of the perceived runs.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from packlab.viz.labels import display_name


def _summaries(argument: str) -> list[dict]:
    return [json.loads((Path(d) / "summary.json").read_text()) for d in argument.split(",")]


def _overall(summaries: list[dict], policy: str) -> tuple[float, float] | None:
    for summary in summaries:
        if policy in summary["table"]:
            cell = summary["table"][policy]["average"]["overall"]
            return cell["mean"], cell["std"]
    return None


def _replans(summaries: list[dict], policy: str) -> float | None:
    for summary in summaries:
        if policy in summary["counts"]:
            return summary["counts"][policy].get("replans_per_episode")
    return None


def _errors(argument: str) -> dict[str, np.ndarray]:
    """Every perceived shown object's dims and yaw error, and every step's heightmap MAE."""
    dims, yaw, mae = [], [], []
    for directory in argument.split(","):
        with open(Path(directory) / "episodes.jsonl", encoding="utf-8") as lines:
            for line in lines:
                for step in json.loads(line).get("steps", []):
                    seen = step.get("perception")
                    if seen:
                        dims += seen["dims_error_mm"]
                        yaw += seen["yaw_error_deg"]
                        mae.append(seen["heightmap_mae_mm"])
    return {"dims_mm": np.array(dims), "yaw_deg": np.array(yaw), "hm_mae_mm": np.array(mae)}


def main(argv: list[str]) -> None:
    if len(argv) != 3:
        sys.exit(__doc__)
    exact, perceived, noisy = (_summaries(a) for a in argv)
    noise = perceived[0].get("sensing", {}).get("noise")
    print(
        f"Average Overall, {exact[0]['suite']}, {exact[0]['backend']}, seeds "
        f"{','.join(map(str, exact[0]['seeds']))}, noise preset {noise}\n"
    )
    print("| Method | exact | perceived | perceived + noisy | loss | re-plans / episode |")
    print("|---|---|---|---|---|---|")
    policies = [p for s in exact for p in s["policies"]]
    for policy in policies:
        cells = [_overall(runs, policy) for runs in (exact, perceived, noisy)]
        if any(c is None for c in cells):
            continue
        text = [f"{m:.3f} ± {s:.3f}" for m, s in cells]
        loss = cells[0][0] - cells[2][0]
        replans = [_replans(runs, policy) for runs in (perceived, noisy)]
        print(
            f"| {display_name(policy)} | "
            + " | ".join(text)
            + f" | {loss:+.3f} | "
            + " / ".join(f"{r:.1f}" for r in replans)
            + " |"
        )
    for label, argument in (("perceived", argv[1]), ("perceived + noisy", argv[2])):
        errors = _errors(argument)
        print(
            f"\nPerception errors ({label}): "
            + "; ".join(
                f"{name} mean {v.mean():.3f}, p95 {np.percentile(v, 95):.3f}, max {v.max():.3f} "
                f"(n = {len(v)})"
                for name, v in errors.items()
            )
        )


if __name__ == "__main__":
    main(sys.argv[1:])
