"""The data of the interactive HTML report: run summaries, cases and compact episode replays.

Pure: typed records and cases in, one JSON-able dict out (``report_data``), embedded once in
the page, from which the browser builds every table, plot and 3D replay. Nothing here depends
on the order records were written in (episodes are sorted), so the same records give the same
dict, and the page the same bytes.

An episode's replay is its steps as arrays (layout in ``STEP_FIELDS``), each step carrying the
poses of the boxes placed or moved at it. Where those come from depends on the record
(``POSE_SOURCES``): current records log them (``StepRecord.poses``); older records of the
geometric backend get them exactly from each step's drop position (that backend never moves a
box once placed); older MuJoCo records have only the final poses, so each box is shown where it
finally settled from the step it was placed at, and the page says so.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from msgspec import UNSET

from packlab.core.choices import DEFAULT_SIDES, SideNames, own_rotation
from packlab.core.records import (
    EpisodeError,
    EpisodeOk,
    EpisodeRecord,
    PoseEntry,
    RunSummary,
    StepRecord,
)
from packlab.core.types import Case
from packlab.metrics import AVERAGE, METRICS
from packlab.sim.episode import INVALID_REASONS
from packlab.sim.heightmap import yaw_quaternion
from packlab.sim.pose_log import pose_entry
from packlab.viz.labels import METRIC_SHORT, display_name, group_title
from packlab.viz.plots import method_colour
from packlab.viz.render import TYPE_COLOURS

#: Version of the embedded data (the page's script reads this layout).
REPORT_DATA_FORMAT = "packlab-report-data-1"
#: A step: object index processed, action ([object_id, rotation, x, y], or the parse error of
#: unparsable output), reason index into ``reasons`` (0: valid), the shown buffer (object
#: indices, in the order shown), the poses placed or moved ([index, x, y, z, qw, qx, qy, qz]).
STEP_FIELDS = ("object", "action", "reason", "shown", "poses")
#: Where an episode's per-step poses come from (see the module docstring).
POSE_SOURCES = {
    "recorded": "as recorded after every step",
    "geometric": "rebuilt exactly from the recorded drop positions (geometric backend; the "
    "record predates per-step poses)",
    "final": "the record predates per-step poses (MuJoCo): each box is shown at its final "
    "settled pose from the step it was placed",
}
#: Row colours of a comparison (matplotlib's tab10).
ROW_COLOURS = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
)
_ERROR_TEXT = 160  # characters of a parse error or failure message kept for the page
_DETAILS = (
    "episodes",
    "errors",
    "invalid_steps",
    "set_aside",
    "unsettled_steps",
    "not_at_rest",
    "decision_ms",
    "step_ms",
    "episode_s",
)


@dataclass(frozen=True, slots=True)
class ReportRun:
    """One run directory as the report sees it."""

    label: str  # the run's name in a comparison ("" for a single run)
    summary: RunSummary
    records: tuple[EpisodeRecord, ...]
    cases: tuple[Case, ...]  # empty when the run directory has no cases.jsonl
    #: The side names the run showed (``packlab.bench.config.run_sides``): recorded rotations
    #: refer to them, so rebuilding a geometric pose needs them.
    sides: SideNames = DEFAULT_SIDES


@dataclass(frozen=True, slots=True)
class Method:
    """A row of the report: one policy of one run."""

    name: str  # as the row is labelled
    run: int  # index into the runs
    policy: str  # the registry name in that run's records
    colour: str


def _r(value: float | None) -> float | None:
    return None if value is None else round(float(value), 6)


def case_entry(case: Case) -> dict[str, Any]:
    """A case's container and boxes (mm) and its objects' ids as the case file gives them."""
    return {
        "id": case.episode_id,
        "level": case.difficulty,
        "container": list(case.container.size_mm),
        "buffer": case.buffer_size,
        "boxes": [[*b.size_mm, b.type_id] for b in case.objects],
        "ids": [str(b.internal_id) for b in case.objects],
    }


def _geometric_pose(case: Case, index: int, rotation: int, drop: Sequence[int]) -> PoseEntry:
    """Where the geometric backend put a box (``GeometricBackend.place``, exactly)."""
    box = case.objects[index]
    fx, fy = box.footprint_mm(rotation)
    centre = (drop[0] + fx / 2, drop[1] + fy / 2, drop[2] + box.size_mm[2] / 2)
    return pose_entry(index, centre, yaw_quaternion(rotation))


def step_poses(
    record: EpisodeOk, case: Case, sides: SideNames = DEFAULT_SIDES
) -> tuple[list[list[PoseEntry]], str]:
    """Per step, the poses placed or moved at it, and their source (a key of POSE_SOURCES)."""
    index_of = {str(b.internal_id): i for i, b in enumerate(case.objects)}
    logged = [s.poses for s in record.steps]
    if all(isinstance(p, tuple) for p in logged):
        return [list(p) for p in logged if isinstance(p, tuple)], "recorded"
    out: list[list[PoseEntry]] = []
    geometric = record.backend == "geometric"
    for s in record.steps:
        index = index_of.get(str(s.internal_id))
        if not s.valid or index is None:
            out.append([])
        elif geometric and s.drop_mm is not None:
            rotation = s.action.rotation if isinstance(s.action.rotation, int) else 0
            own = own_rotation(case.objects[index].size_mm, rotation, sides)
            out.append([_geometric_pose(case, index, own, s.drop_mm)])
        else:
            final = record.final_poses.get(str(s.internal_id))
            out.append(
                [] if final is None else [pose_entry(index, final.position_mm, final.quaternion)]
            )
    return out, "geometric" if geometric else "final"


def _action(step: StepRecord) -> list[int] | str:
    a = step.action
    placement = a.placement()
    if placement is None:  # the {unparsable, error} form
        return f"unparsable: {a.error}"[:_ERROR_TEXT]
    return list(placement)


def episode_steps(
    record: EpisodeOk, case: Case, sides: SideNames = DEFAULT_SIDES
) -> tuple[list[list[Any]], str]:
    """The replay of an episode (STEP_FIELDS per step) and where its poses come from."""
    index_of = {str(b.internal_id): i for i, b in enumerate(case.objects)}
    poses, source = step_poses(record, case, sides)
    reasons = {r: i + 1 for i, r in enumerate(INVALID_REASONS)}
    steps = []
    for s, moved in zip(record.steps, poses):
        steps.append(
            [
                index_of.get(str(s.internal_id), -1),
                _action(s),
                0 if s.valid else reasons.get(s.reason, len(INVALID_REASONS) + 1),
                [index_of.get(str(i), -1) for i in s.shown],
                [list(e) for e in moved],
            ]
        )
    return steps, source


def episode_entry(
    record: EpisodeRecord,
    method: int,
    case_index: int,
    case: Case | None,
    sides: SideNames = DEFAULT_SIDES,
) -> dict[str, Any]:
    """One episode: who, what it scored, and its replay when the case is known."""
    head: dict[str, Any] = {"m": method, "c": case_index, "s": record.seed}
    if isinstance(record, EpisodeError):
        return {**head, "error": f"{record.error_kind}: {record.error}"[:_ERROR_TEXT]}
    assert isinstance(record, EpisodeOk)
    if record.reused_from_seed is not UNSET:  # a copy of a seed-free policy's episode
        head["reused_from"] = record.reused_from_seed
    m = record.metrics
    head["metrics"] = {
        "overall": _r(m.overall),
        "success_ratio": _r(m.success_ratio),
        "compactness": _r(m.compactness),
        "inside": m.n_inside,
        "objects": m.n_objects,
        "set_aside": m.n_set_aside,
        "invalid": sum(1 for s in record.steps if not s.valid and s.reason != "set_aside"),
        "at_rest": m.at_rest,
        "max_height_mm": m.max_height_mm,
        "policy_s": _r(record.policy_time_s),
    }
    if case is not None:
        head["steps"], head["poses"] = episode_steps(record, case, sides)
    return head


def _groups(summary: RunSummary) -> list[str]:
    groups = list(summary.difficulties)
    return groups + [AVERAGE] if len(groups) > 1 else groups


def method_entry(method: Method, summary: RunSummary) -> dict[str, Any]:
    """A row: its table cells ([mean, std] per group and metric) and its counters."""
    table = summary.table.get(method.policy, {})
    cells = []
    for g in _groups(summary):
        for metric in METRICS:
            cell = table[g].cell(metric) if g in table else None
            cells.append(None if cell is None else [_r(cell.mean), _r(cell.std)])
    c = summary.counts.get(method.policy)
    counts = {k: getattr(c, k) if c is not None else None for k in _DETAILS}
    return {
        "name": method.name,
        "policy": method.policy,
        "run": method.run,
        "colour": method.colour,
        "cells": cells,
        "counts": {k: _r(v) if isinstance(v, float) else v for k, v in counts.items()},
    }


def _case_table(runs: Sequence[ReportRun]) -> tuple[list[dict[str, Any]], dict[str, Case]]:
    """Every case of the runs (by id, in the first run's order), and the known ones by id."""
    known: dict[str, Case] = {}
    for run in runs:
        for case in run.cases:
            known.setdefault(case.episode_id, case)
    levels: dict[str, str] = {}
    for run in runs:
        for r in run.records:
            levels.setdefault(r.case_id, r.difficulty)
    entries = [case_entry(c) for c in known.values()]
    for case_id in sorted(set(levels) - set(known)):
        entries.append({"id": case_id, "level": levels[case_id], "boxes": None})
    return entries, known


def report_data(
    runs: Sequence[ReportRun],
    methods: Sequence[Method],
    *,
    title: str,
    subtitle: str,
    initial_case: str | None = None,
    notes: Sequence[str] = (),
    headline: str = "",
    replay: Sequence[int] = (),
    differences: Sequence[str] = (),
) -> dict[str, Any]:
    """Everything the page shows, as one JSON-able dict (see the module docstring).

    ``headline``: the page's one calm first line; ``notes``: what needs the reader's attention
    (the data's own notes are added); ``replay``: the rows the two replay panes open on
    (default the first two); ``differences``: a comparison's paired differences, one line
    each, shown under its table."""
    first = runs[0].summary
    cases, known = _case_table(runs)
    case_index = {c["id"]: i for i, c in enumerate(cases)}
    row_of: Mapping[tuple[int, str], int] = {(m.run, m.policy): i for i, m in enumerate(methods)}
    episodes = []
    for run_i, run in enumerate(runs):
        seeds, levels = set(run.summary.seeds), set(run.summary.difficulties)
        for r in run.records:
            row = row_of.get((run_i, r.policy))
            if row is None or r.seed not in seeds or r.difficulty not in levels:
                continue
            case = known.get(r.case_id)
            episodes.append(episode_entry(r, row, case_index[r.case_id], case, run.sides))
    episodes.sort(key=lambda e: (e["m"], e["c"], e["s"]))
    groups = _groups(first)
    return {
        "format": REPORT_DATA_FORMAT,
        "title": title,
        "subtitle": subtitle,
        "headline": headline,
        "notes": [*notes, *data_notes(cases, episodes)],
        "differences": list(differences),
        "runs": [{"label": run.label, "backend": run.summary.backend or None} for run in runs],
        "seeds": list(first.seeds),
        "levels": list(first.difficulties),
        "groups": [[g, group_title(g)] for g in groups],
        "metrics": [[m, METRIC_SHORT[m]] for m in METRICS],
        "methods": [method_entry(m, runs[m.run].summary) for m in methods],
        "reasons": ["", *INVALID_REASONS, "other"],
        "pose_sources": POSE_SOURCES,
        "type_colours": TYPE_COLOURS,
        "cases": cases,
        "episodes": episodes,
        "initial_case": initial_case if initial_case in case_index else None,
        "replay": _replay_rows(replay, len(methods)),
    }


def _replay_rows(rows: Sequence[int], n_methods: int) -> list[int]:
    """Two row indices for the replay panes: ``rows`` where valid, else the first two rows."""
    if len(rows) == 2 and all(0 <= r < n_methods for r in rows):
        return [int(r) for r in rows]
    return [0, 1 if n_methods > 1 else 0]


def data_notes(
    cases: Sequence[Mapping[str, Any]], episodes: Sequence[Mapping[str, Any]]
) -> list[str]:
    """What the reader should know about the data: failures, replays missing or approximate."""
    notes = []
    failed = sum(1 for e in episodes if "error" in e)
    if failed:
        notes.append(
            f"{failed} episode(s) failed: left out of the means, listed first in the case browser."
        )
    unknown = sum(1 for c in cases if c["boxes"] is None)
    if unknown:
        notes.append(
            f"{unknown} case(s) of the records are not in the run's cases.jsonl: their episodes "
            "are scored but cannot be replayed."
        )
    final = sum(1 for e in episodes if e.get("poses") == "final")
    if final:
        notes.append(
            f"{final} episode(s) were recorded before records kept per-step poses; replays of "
            "MuJoCo ones show each box at its final settled pose from the step it was placed."
        )
    return notes


def row_colours(policies: Sequence[str], distinct: bool) -> list[str]:
    """A colour per row: the method's own (as in every figure), or, in a comparison where a
    method can appear once per run, one colour per row."""
    if not distinct:
        return [method_colour(p, list(policies)) for p in policies]
    return [ROW_COLOURS[i % len(ROW_COLOURS)] for i in range(len(policies))]


def method_name(label: str, policy: str, n_policies: int) -> str:
    """A row's name: the method's display name; in a comparison ``"<run>: <method>"`` (just the
    run's label when that run has one method), as ``packlab bench compare`` names rows."""
    if not label:
        return display_name(policy)
    return label if n_policies == 1 else f"{label}: {display_name(policy)}"


__all__ = [
    "POSE_SOURCES",
    "REPORT_DATA_FORMAT",
    "ROW_COLOURS",
    "STEP_FIELDS",
    "Method",
    "ReportRun",
    "case_entry",
    "data_notes",
    "episode_entry",
    "episode_steps",
    "method_entry",
    "method_name",
    "report_data",
    "row_colours",
    "step_poses",
]
