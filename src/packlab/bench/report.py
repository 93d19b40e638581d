"""``packlab bench report DIR``: tables and figures of a run, rebuilt from its files alone.

``build_report`` reads ``config.json``, ``episodes.jsonl`` and ``cases.jsonl`` and nothing
else (no engine, no policy), so a report can be made anywhere, any time after a run, and it is
identical to what the run printed (``write_outputs`` is shared by both).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from packlab.bench.records import CASES_FILE, CONFIG_FILE, EPISODES_FILE, read_records
from packlab.bench.summary import summarize
from packlab.bench.table import render_markdown
from packlab.cases import load_cases
from packlab.core.errors import ConfigError
from packlab.core.types import Case

SUMMARY_FILE = "summary.json"
TABLE_FILE = "table.md"
FIGURE_BOX = "overall_by_case.png"
FIGURE_BARS = "overall_average.png"
#: Summary meta fields copied from config.json.
_META_KEYS = ("suite", "backend", "n_cases", "cases_sha256")


@dataclass(frozen=True, slots=True)
class RunFiles:
    """A run directory as read from disk."""

    run_dir: Path
    config: dict[str, Any]
    records: list[dict[str, Any]]
    cases: tuple[Case, ...]  # empty when cases.jsonl is missing (figures of packings then skip)


def load_run(run_dir: str | os.PathLike[str]) -> RunFiles:
    root = Path(run_dir)
    cfg_path = root / CONFIG_FILE
    if not cfg_path.is_file():
        raise ConfigError(f"{root}: no {CONFIG_FILE}; not a bench run directory")
    try:
        config = json.loads(cfg_path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{cfg_path}: unreadable JSON ({exc.msg})") from None
    for key in ("policies", "seeds", "difficulties"):
        if not isinstance(config.get(key), list):
            raise ConfigError(f"{cfg_path}: field '{key}' = {config.get(key)!r}: expected a list")
    cases_path = root / CASES_FILE
    cases = tuple(load_cases(cases_path)) if cases_path.is_file() else ()
    return RunFiles(root, config, read_records(root / EPISODES_FILE), cases)


def summary_of(config: dict[str, Any], records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The run's summary with the configuration's order of methods, seeds and difficulties."""
    meta = {k: config.get(k) for k in _META_KEYS}
    return summarize(records, config["policies"], config["seeds"], config["difficulties"], meta=meta)


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)


def pick_showcase_case(summary: dict[str, Any], cases: Sequence[Case]) -> str | None:
    """A typical case of the hardest level: median mean-Overall over the non-oracle methods.

    The median (not the best or worst case) so the picture shows what the table averages.
    """
    if not cases:
        return None
    level = summary["difficulties"][-1] if summary["difficulties"] else None
    scored = []
    for case in cases:
        if case.difficulty != level:
            continue
        vals = [summary["per_case"][p][case.episode_id]["overall"]["mean"]
                for p in summary["policies"] if p != "oracle" and case.episode_id in summary["per_case"].get(p, {})]
        vals = [v for v in vals if v is not None]
        if vals:
            scored.append((sum(vals) / len(vals), case.episode_id))
    if not scored:
        return None
    scored.sort()
    return scored[len(scored) // 2][1]


def write_figures(run_dir: Path, summary: dict[str, Any], records: Sequence[dict[str, Any]],
                  cases: Sequence[Case], case_id: str | None = None, seed: int | None = None) -> list[Path]:
    """The distribution box plot, the average bar chart and one case's side-by-side packings."""
    from packlab.viz.plots import average_overall_figure, overall_distribution_figure, save_figure
    from packlab.viz.render import packing_comparison_figure

    paths = [save_figure(overall_distribution_figure(summary), run_dir / FIGURE_BOX),
             save_figure(average_overall_figure(summary), run_dir / FIGURE_BARS)]
    case_id = case_id or pick_showcase_case(summary, cases)
    by_id = {c.episode_id: c for c in cases}
    if case_id is not None:
        if case_id not in by_id:
            raise ConfigError(f"case = {case_id!r}: not in this run's {CASES_FILE}")
        seed = summary["seeds"][0] if seed is None else seed
        chosen = {r["policy"]: r for r in records
                  if r["case_id"] == case_id and int(r["seed"]) == seed and r.get("status", "ok") == "ok"}
        entries = [(p, chosen[p]) for p in summary["policies"] if p in chosen]
        if entries:
            fig = packing_comparison_figure(by_id[case_id], entries, seed)
            paths.append(save_figure(fig, run_dir / f"packing_{case_id}_seed{seed}.png"))
    return paths


def write_outputs(run_dir: str | os.PathLike[str], config: dict[str, Any], records: Sequence[dict[str, Any]],
                  cases: Sequence[Case], figures: bool = True, case_id: str | None = None,
                  seed: int | None = None) -> tuple[dict[str, Any], str, list[Path]]:
    """Write summary.json, table.md and (optionally) the figures; return (summary, table, paths)."""
    root = Path(run_dir)
    summary = summary_of(config, records)
    table_md = render_markdown(summary)
    _atomic_text(root / SUMMARY_FILE, json.dumps(summary, indent=1) + "\n")
    _atomic_text(root / TABLE_FILE, table_md)
    paths = [root / SUMMARY_FILE, root / TABLE_FILE]
    if figures and any(r.get("status", "ok") == "ok" for r in records):
        paths += write_figures(root, summary, records, cases, case_id, seed)
    return summary, table_md, paths


def build_report(run_dir: str | os.PathLike[str], figures: bool = True, case_id: str | None = None,
                 seed: int | None = None) -> tuple[dict[str, Any], str, list[Path]]:
    """Rebuild summary, table and figures of a run directory from its files."""
    run = load_run(run_dir)
    if not run.records:
        raise ConfigError(f"{run.run_dir / EPISODES_FILE}: no records; nothing to report")
    if seed is not None and seed not in run.config.get("seeds", []):
        raise ConfigError(f"seed = {seed!r}: not a seed of this run (seeds {run.config.get('seeds')})")
    return write_outputs(run.run_dir, run.config, run.records, run.cases, figures, case_id, seed)


__all__ = ["RunFiles", "build_report", "load_run", "pick_showcase_case", "summary_of", "write_figures",
           "write_outputs"]
