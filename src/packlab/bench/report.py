"""``packlab bench report DIR``: tables and figures of a run, rebuilt from its files alone.

``build_report`` reads ``config.json``, ``episodes.jsonl`` and ``cases.jsonl`` and nothing
else (no engine, no policy), so a report can be made anywhere, any time after a run, and it is
identical to what the run printed (``write_outputs`` is shared by both). Every file is read as
its typed record with its format version checked (``packlab.core.records``): a run-1 directory
still reports (its records migrate), a newer one is refused naming the file and field.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from packlab.bench.records import CASES_FILE, CONFIG_FILE, EPISODES_FILE, read_records
from packlab.bench.summary import RunIntervals, run_intervals, summarize
from packlab.bench.table import render_markdown
from packlab.cases import load_cases
from packlab.core.errors import ConfigError
from packlab.core.records import (
    EpisodeOk,
    EpisodeRecord,
    NotJSON,
    RunConfigHead,
    RunSummary,
    convert,
    run_config_from_json,
    to_builtins,
)
from packlab.core.types import Case
from packlab.viz.plots import average_overall_figure, overall_distribution_figure, save_figure
from packlab.viz.render import packing_comparison_figure

SUMMARY_FILE = "summary.json"
TABLE_FILE = "table.md"
FIGURE_BOX = "overall_by_case.png"
FIGURE_BARS = "overall_average.png"


@dataclass(frozen=True, slots=True)
class RunFiles:
    """A run directory as read from disk."""

    run_dir: Path
    config: RunConfigHead
    records: list[EpisodeRecord]
    cases: tuple[Case, ...]  # empty when cases.jsonl is missing (figures of packings then skip)


def load_run(run_dir: str | os.PathLike[str]) -> RunFiles:
    root = Path(run_dir)
    cfg_path = root / CONFIG_FILE
    if not cfg_path.is_file():
        raise ConfigError(f"{root}: no {CONFIG_FILE}; not a bench run directory")
    try:
        config = run_config_from_json(cfg_path.read_bytes(), str(cfg_path))
    except NotJSON as exc:
        raise ConfigError(f"{exc}; not a bench run directory?") from None
    cases_path = root / CASES_FILE
    cases = tuple(load_cases(cases_path)) if cases_path.is_file() else ()
    return RunFiles(root, config, read_records(root / EPISODES_FILE), cases)


def config_head(config: RunConfigHead | Mapping[str, object]) -> RunConfigHead:
    """A run's config as the report reads it: config.json's typed head, or the resolved
    config's JSON (``ResolvedRun.to_json()``) checked into one."""
    if isinstance(config, RunConfigHead):
        return config
    return convert(dict(config), RunConfigHead, CONFIG_FILE)


def summary_of(
    config: RunConfigHead | Mapping[str, object],
    records: Sequence[EpisodeRecord],
    cases: Sequence[Case] = (),
) -> RunSummary:
    """The run's summary with the configuration's order of methods, seeds and difficulties;
    ``cases`` (the run's) give buffer-protocol records their space utilization."""
    head = config_head(config)
    volumes = {c.episode_id: container_volume_mm3(c) for c in cases}
    return summarize(
        records, head.policies, head.seeds, head.difficulties, meta=head, container_mm3=volumes
    )


def container_volume_mm3(case: Case) -> int:
    x, y, z = case.container.size_mm
    return int(x) * int(y) * int(z)


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)


def summary_json(summary: RunSummary, intervals: RunIntervals | None = None) -> str:
    """summary.json's text (the layout ``json.dumps(indent=1)`` has always written), with the
    bootstrap intervals under an added ``intervals`` key (``packlab.bench.summary.RunIntervals``;
    readers of the older layout ignore it)."""
    intervals = run_intervals(summary) if intervals is None else intervals
    obj = {**to_builtins(summary), "intervals": to_builtins(intervals)}
    return json.dumps(obj, indent=1) + "\n"


def pick_showcase_case(summary: RunSummary, cases: Sequence[Case]) -> str | None:
    """A typical case of the hardest level: median mean-Overall over the non-oracle methods.

    The median (not the best or worst case) so the picture shows what the table averages.
    """
    if not cases:
        return None
    level = summary.difficulties[-1] if summary.difficulties else None
    scored = []
    for case in cases:
        if case.difficulty != level:
            continue
        vals = [
            summary.per_case[p][case.episode_id].overall.mean
            for p in summary.policies
            if p != "oracle" and case.episode_id in summary.per_case.get(p, {})
        ]
        scores = [v for v in vals if v is not None]
        if scores:
            scored.append((sum(scores) / len(scores), case.episode_id))
    if not scored:
        return None
    scored.sort()
    return scored[len(scored) // 2][1]


def write_figures(
    run_dir: Path,
    summary: RunSummary,
    records: Sequence[EpisodeRecord],
    cases: Sequence[Case],
    case_id: str | None = None,
    seed: int | None = None,
    intervals: RunIntervals | None = None,
) -> list[Path]:
    """The distribution box plot, the average bar chart (bootstrap intervals as error bars;
    computed here when not given) and one case's side-by-side packings."""
    intervals = run_intervals(summary) if intervals is None else intervals
    paths = [
        save_figure(overall_distribution_figure(summary), run_dir / FIGURE_BOX),
        save_figure(average_overall_figure(summary, intervals), run_dir / FIGURE_BARS),
    ]
    case_id = case_id or pick_showcase_case(summary, cases)
    by_id = {c.episode_id: c for c in cases}
    if case_id is not None:
        if case_id not in by_id:
            raise ConfigError(f"case = {case_id!r}: not in this run's {CASES_FILE}")
        seed = summary.seeds[0] if seed is None else seed
        chosen = {
            r.policy: r
            for r in records
            if isinstance(r, EpisodeOk) and r.case_id == case_id and r.seed == seed
        }
        entries = [(p, chosen[p]) for p in summary.policies if p in chosen]
        if entries:
            fig = packing_comparison_figure(by_id[case_id], entries, seed)
            paths.append(save_figure(fig, run_dir / f"packing_{case_id}_seed{seed}.png"))
    return paths


def write_outputs(
    run_dir: str | os.PathLike[str],
    config: RunConfigHead | Mapping[str, object],
    records: Sequence[EpisodeRecord],
    cases: Sequence[Case],
    figures: bool = True,
    case_id: str | None = None,
    seed: int | None = None,
) -> tuple[RunSummary, str, list[Path]]:
    """Write summary.json, table.md and (optionally) the figures; return (summary, table, paths)."""
    root = Path(run_dir)
    summary = summary_of(config, records, cases)
    intervals = run_intervals(summary)  # one bootstrap for both files
    table_md = render_markdown(summary, intervals)
    _atomic_text(root / SUMMARY_FILE, summary_json(summary, intervals))
    _atomic_text(root / TABLE_FILE, table_md)
    paths = [root / SUMMARY_FILE, root / TABLE_FILE]
    if figures and any(isinstance(r, EpisodeOk) for r in records):
        paths += write_figures(root, summary, records, cases, case_id, seed, intervals)
    return summary, table_md, paths


def build_report(
    run_dir: str | os.PathLike[str],
    figures: bool = True,
    case_id: str | None = None,
    seed: int | None = None,
) -> tuple[RunSummary, str, list[Path]]:
    """Rebuild summary, table and figures of a run directory from its files."""
    run = load_run(run_dir)
    if not run.records:
        raise ConfigError(f"{run.run_dir / EPISODES_FILE}: no records; nothing to report")
    if seed is not None and seed not in run.config.seeds:
        raise ConfigError(
            f"seed = {seed!r}: not a seed of this run (seeds {list(run.config.seeds)})"
        )
    return write_outputs(run.run_dir, run.config, run.records, run.cases, figures, case_id, seed)


__all__ = [
    "RunFiles",
    "build_report",
    "config_head",
    "load_run",
    "pick_showcase_case",
    "summary_json",
    "summary_of",
    "write_figures",
    "write_outputs",
]
