r"""The planner's tables: both frozen suites, full visibility, fresh layered, stepped, random sets.

Usage:
    python benchmarks/plan_tables.py --out runs/plan-tables             # everything, 3 seeds
    python benchmarks/plan_tables.py --out runs/plan-tables --sets stepped,random --seeds 0
    python benchmarks/plan_tables.py --out runs/plan-tables --report    # tables only, no runs
    python benchmarks/plan_tables.py --out runs/plan-tables --sets removal --mode stereo \
        --policies plan-fast,irbpp --reference plan-fast                # the robot path

``--mode`` runs the sets on the robot path (``honest``: perceived + noisy execution + depth
segmentation, the buffer's boxes touching) under a sensor and robot preset, into
``OUT/<set>-<mode>/``; with an exact run of the same set in ``OUT/<set>/`` the report adds each
row's paired loss exact minus honest.

Each case set is written once under ``OUT/cases/`` and run with ``packlab bench`` into
``OUT/<set>/`` (resumable: rerun the same command after a crash). The report reads the records
only: per level the mean Overall with a 95 % bootstrap interval over cases (each case's mean over
the run seeds first), the policy's mean milliseconds per decision on that level (one worker
process, i.e. one core), and for ``plan`` the paired difference to every other row (bootstrap
over cases; a row differs only when the interval excludes zero); then each policy's decision time
per level as mean / p95 / max milliseconds (from the steps' own timings), so a heavy tail shows.

Case sets (fresh sets use seeds used nowhere else, in the ``train`` seed domain, never the
bench's; the full-visibility sets set every case's ``buffer_size`` to its number of objects):

* ``removal``: packlab-bench-v1 (boxes arrive after their supports, layers interleave);
* ``layers``: packlab-bench-layers-v1 (layer by layer, shuffled within a layer);
* ``removal-full``, ``layers-full``: the same cases with every box in view;
* ``layered-fresh``: 60 new layered cases in layer order (the suites' recipe);
* ``removal-fresh``: 60 new layered cases in reverse-removal order (packlab-bench-v1's);
* ``stepped``, ``random``: 60 new cases of the stepped family and of independently drawn boxes.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from packlab.bench.decision_times import decision_times
from packlab.bench.records import read_records
from packlab.bench.suites import load_suite
from packlab.cases import save_cases
from packlab.core.records import EpisodeOk
from packlab.core.types import Case
from packlab.datagen import generate_cases
from packlab.datagen.config import CaseConfig

LEVELS = ("easy", "medium", "hard")
PER_LEVEL = 20
#: Seeds of the fresh sets: used by nothing else in the repository.
FRESH_SEEDS = {
    "layered-fresh": 92_501,
    "stepped": 92_502,
    "random": 92_503,
    "removal-fresh": 92_504,
}
COMPARED = "plan,plan-fast,plan-lookahead,sdf,proposer"
POLICIES = {
    "layers": COMPARED,
    "removal": COMPARED,
    "layers-full": "plan,plan-fast",
    "removal-full": "plan,plan-fast",
    "layered-fresh": "plan,plan-fast",
    "removal-fresh": "plan,plan-fast",
    "stepped": COMPARED,
    "random": COMPARED,
}
SUITES = {"removal": "packlab-bench-v1", "layers": "packlab-bench-layers-v1"}


def build_cases(name: str) -> list[Case]:
    """The cases of one set (see the module docstring)."""
    base = name.removesuffix("-full")
    if base in SUITES:
        cases = load_suite(SUITES[base])
        if name.endswith("-full"):
            cases = [dataclasses.replace(c, buffer_size=len(c.objects)) for c in cases]
        return cases
    config = {
        "layered-fresh": CaseConfig(order="layers"),
        "removal-fresh": CaseConfig(order="removal"),
        "stepped": CaseConfig(layout="stepped"),
        "random": CaseConfig(layout="random"),
    }[name]
    return [
        case
        for level in LEVELS
        for case in generate_cases(
            level, PER_LEVEL, FRESH_SEEDS[name], config=config, domain="train"
        )
    ]


#: The robot path's modes: ``packlab bench`` options of each (exact: none).
_HONEST = ["--observation", "perceived", "--execution", "noisy", "--segmentation", "depth"]
MODES: dict[str, list[str]] = {
    "exact": [],
    **{preset: [*_HONEST, "--noise", preset] for preset in ("structured-light", "stereo")},
}


def run_dir(out: Path, name: str, mode: str) -> Path:
    return out / (name if mode == "exact" else f"{name}-{mode}")


def run_set(
    name: str, out: Path, seeds: str, backend: str, policies: str, mode: str = "exact"
) -> None:
    cases_path = out / "cases" / f"{name}.jsonl"
    if not cases_path.is_file():
        cases_path.parent.mkdir(parents=True, exist_ok=True)
        save_cases(build_cases(name), cases_path)
    command = [
        sys.executable, "-m", "packlab.cli.main", "bench", "--cases", str(cases_path),
        "--policies", policies, "--seeds", seeds, "--backend", backend,
        "--out", str(run_dir(out, name, mode)), "--no-html", "--no-figures", *MODES[mode],
    ]  # fmt: skip
    print("+", " ".join(command), flush=True)
    subprocess.run(command, check=True)


def _bootstrap(values: np.ndarray, rng: np.random.Generator, n: int = 2000) -> tuple[float, float]:
    means = values[rng.integers(0, values.size, (n, values.size))].mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def _records(run_dir: Path) -> dict[str, dict[str, dict]]:
    """policy -> case -> {"level", "overall" (mean over seeds), "policy_s", "decisions"}."""
    out: dict[str, dict[str, dict]] = {}
    with open(run_dir / "episodes.jsonl", encoding="utf-8") as fh:
        for line in fh:
            r = json.loads(line)
            if r.get("status") != "ok":
                continue
            row = out.setdefault(r["policy"], {}).setdefault(
                r["case_id"],
                {"level": r["difficulty"], "overall": [], "policy_s": 0.0, "decisions": 0},
            )
            row["overall"].append(r["metrics"]["overall"])
            row["policy_s"] += r["timing"]["policy_s"]
            row["decisions"] += r["timing"]["decisions"]
    return out


def report_set(
    name: str, run_dir: Path, reference: str = "plan", exact_dir: Path | None = None
) -> str:
    """The markdown table of one set (see the module docstring): paired differences of
    ``reference`` minus every other row and, given the same set's exact run, each row's loss."""
    rng = np.random.default_rng(0)
    records = _records(run_dir)
    lines = [
        f"### {run_dir.name}",
        "",
        "| Method | " + " | ".join(f"{lv.capitalize()} Overall" for lv in LEVELS)
        + " | Average Overall | ms / decision (" + " / ".join(LEVELS) + ") |",
        "| --- |" + " ---: |" * (len(LEVELS) + 2),
    ]  # fmt: skip
    for policy, cases in sorted(records.items(), key=lambda kv: -_mean(kv[1])):
        cells = []
        for level in (*LEVELS, None):
            vals = np.array(
                [np.mean(c["overall"]) for c in cases.values() if level in (None, c["level"])]
            )
            lo, hi = _bootstrap(vals, rng)
            cells.append(f"{vals.mean():.3f} [{lo:.3f}, {hi:.3f}]")
        ms = []
        for level in LEVELS:
            rows = [c for c in cases.values() if c["level"] == level]
            decisions = sum(c["decisions"] for c in rows)
            ms.append(f"{1000 * sum(c['policy_s'] for c in rows) / max(decisions, 1):.0f}")
        lines.append(f"| {policy} | " + " | ".join(cells) + f" | {' / '.join(ms)} |")
    lines += ["", *decision_tails(run_dir)]
    if reference in records:
        lines += [
            "",
            f"Paired difference, {reference} minus each row (95 % bootstrap over cases):",
            "",
        ]
        ref = records[reference]
        for policy, cases in sorted(records.items()):
            if policy != reference:
                lines.append(f"- vs {policy}: {_paired(ref, cases, rng)}")
    exact = _records(exact_dir) if exact_dir and (exact_dir / "episodes.jsonl").is_file() else {}
    losses = [p for p in records if p in exact]
    if losses:
        lines += ["", "Loss, exact minus this mode, per row (paired over cases):", ""]
        lines += [f"- {p}: {_paired(exact[p], records[p], rng)}" for p in sorted(losses)]
    return "\n".join(lines) + "\n"


def _paired(a: dict[str, dict], b: dict[str, dict], rng: np.random.Generator) -> str:
    """Mean of a minus b over their common cases, its 95 % bootstrap interval and verdict."""
    common = sorted(set(a) & set(b))
    if not common:
        return "no common cases"
    d = np.array([np.mean(a[c]["overall"]) - np.mean(b[c]["overall"]) for c in common])
    lo, hi = _bootstrap(d, rng)
    verdict = "higher" if lo > 0 else ("lower" if hi < 0 else "no difference")
    return f"{d.mean():+.3f} [{lo:+.3f}, {hi:+.3f}] ({verdict})"


def decision_tails(run_dir: Path) -> list[str]:
    """Per policy and level: mean / p95 / max ms per decision (wall), from the steps' own
    ``decision_s`` (records written before they existed show "-"): the mean alone hides the
    steps a robot cell would wait seconds for."""
    by_policy: dict[str, list[EpisodeOk]] = {}
    for r in read_records(run_dir / "episodes.jsonl"):
        if isinstance(r, EpisodeOk):
            by_policy.setdefault(r.policy, []).append(r)
    lines = [
        "Decision time, ms (wall, one core): mean / p95 / max per level",
        "",
        "| Method | " + " | ".join(LEVELS) + " |",
        "| --- |" + " ---: |" * len(LEVELS),
    ]
    for policy, recs in sorted(by_policy.items()):
        times = decision_times(recs, LEVELS) or {}
        cells = [
            "-" if lv not in times
            else f"{times[lv].mean_ms:.0f} / {times[lv].p95_ms:.0f} / {times[lv].max_ms:.0f}"
            for lv in LEVELS
        ]  # fmt: skip
        lines.append(f"| {policy} | " + " | ".join(cells) + " |")
    return lines


def _mean(cases: dict[str, dict]) -> float:
    return float(np.mean([np.mean(c["overall"]) for c in cases.values()]))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="directory for case files and run directories")
    p.add_argument("--sets", default=",".join(POLICIES), help="comma-separated case sets")
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--backend", default="mujoco", choices=("mujoco", "geometric"))
    p.add_argument("--policies", help="override every set's policy list")
    p.add_argument("--report", action="store_true", help="print the tables from existing runs")
    p.add_argument(
        "--mode", default="exact", choices=tuple(MODES), help="exact, or honest under a preset"
    )
    p.add_argument("--reference", default="plan", help="the row paired differences are taken from")
    args = p.parse_args(argv)
    out = Path(args.out)
    names = [n for n in args.sets.split(",") if n]
    unknown = sorted(set(names) - set(POLICIES))
    if unknown:
        p.error(f"--sets: unknown {unknown}; choose from {', '.join(POLICIES)}")
    for name in names:
        policies = args.policies or POLICIES[name]
        if not args.report:
            run_set(name, out, args.seeds, args.backend, policies, args.mode)
        here = run_dir(out, name, args.mode)
        if (here / "episodes.jsonl").is_file():
            exact = None if args.mode == "exact" else run_dir(out, name, "exact")
            print(report_set(name, here, args.reference, exact))
    return 0


if __name__ == "__main__":
    sys.exit(main())
