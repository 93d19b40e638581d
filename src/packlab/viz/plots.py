"""Bench figures from a run summary: per-case Overall distributions and average-Overall bars;
the SFT loss curve of a training run (``plot_loss_curve``).

Figures are built on ``matplotlib.figure.Figure`` directly (no pyplot state, no GUI backend), so
they can be made in worker processes and tests alike; ``save_figure`` writes PNGs via Agg.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from msgspec import UnsetType

from packlab.core.records import RunSummary
from packlab.metrics import AVERAGE
from packlab.viz.labels import display_name, group_title

#: Fixed colours, so a method looks the same in every figure of every run.
_METHOD_COLOURS = {
    "dblf": "#4C72B0",
    "hm": "#55A868",
    "mta": "#C44E52",
    "ffp": "#8172B2",
    "sdf": "#DD8452",
    "random": "#9A9A9A",
    "oracle": "#333333",
}
_EXTRA = ["#64B5CD", "#CCB974", "#DA8BC3", "#8C613C", "#2F9E8F", "#B279A2"]
#: Difficulty shading of grouped bars (light to dark), the average in a saturated tone.
_GROUP_ALPHA = {0: 0.35, 1: 0.55, 2: 0.75}


def method_colour(policy: str, order: list[str] | None = None) -> str:
    if policy in _METHOD_COLOURS:
        return _METHOD_COLOURS[policy]
    extras = [p for p in (order or [policy]) if p not in _METHOD_COLOURS]
    return _EXTRA[(extras.index(policy) if policy in extras else 0) % len(_EXTRA)]


def save_figure(fig: Figure, path: str | os.PathLike[str], dpi: int = 130) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    fig.savefig(tmp, dpi=dpi, bbox_inches="tight", facecolor="white")
    tmp.replace(path)
    return path


def _case_overall(summary: RunSummary, policy: str, difficulty: str) -> np.ndarray:
    """Per-case Overall (mean over seeds) of one method on one difficulty."""
    per_case = summary.per_case.get(policy, {})
    vals = [
        c.overall.mean
        for c in per_case.values()
        if c.difficulty == difficulty and c.overall.mean is not None
    ]
    return np.asarray(vals, dtype=float)


def _run_field(summary: RunSummary, name: str, default: str) -> Any:
    """A run field of the summary (suite, backend); ``default`` when the summary has none."""
    value = getattr(summary, name)
    return default if isinstance(value, UnsetType) else value


def overall_distribution_figure(summary: RunSummary) -> Figure:
    """One panel per difficulty: a box per method over its cases' Overall, with every case as a dot.

    Each dot is one case's Overall averaged over the run seeds; dots are jittered sideways with
    a fixed RNG so the picture is the same every time it is rebuilt.
    """
    policies, groups = list(summary.policies), list(summary.difficulties)
    fig = Figure(figsize=(max(6.0, 0.55 * len(policies) * len(groups) + 2.0), 4.4))
    axes = fig.subplots(1, len(groups), sharey=True, squeeze=False)[0]
    rng = np.random.default_rng(0)
    for ax, group in zip(axes, groups):
        data = [_case_overall(summary, p, group) for p in policies]
        pos = np.arange(1, len(policies) + 1)
        shown = [(i, d) for i, d in enumerate(data) if d.size]
        if shown:
            bp = ax.boxplot(
                [d for _, d in shown],
                positions=[pos[i] for i, _ in shown],
                widths=0.62,
                patch_artist=True,
                showfliers=False,
                medianprops={"color": "black", "linewidth": 1.4},
                whiskerprops={"color": "#555555"},
                capprops={"color": "#555555"},
            )
            for patch, (i, _) in zip(bp["boxes"], shown):
                patch.set_facecolor(method_colour(policies[i], policies))
                patch.set_alpha(0.35)
                patch.set_edgecolor("#444444")
        for i, d in shown:
            jitter = rng.uniform(-0.17, 0.17, size=d.size)
            ax.scatter(
                pos[i] + jitter,
                d,
                s=13,
                color=method_colour(policies[i], policies),
                alpha=0.85,
                edgecolors="white",
                linewidths=0.4,
                zorder=3,
            )
        n_cases = max((d.size for d in data), default=0)
        ax.set_title(f"{group_title(group)} ({n_cases} cases)", fontsize=11)
        ax.set_xticks(pos)
        ax.set_xticklabels(
            [display_name(p).replace(" (gt plan)", "") for p in policies],
            rotation=35,
            ha="right",
            fontsize=9,
        )
        ax.set_ylim(-0.02, 1.05)
        ax.grid(axis="y", color="#DDDDDD", linewidth=0.7)
        ax.set_axisbelow(True)
        for side in ("top", "right"):
            ax.spines[side].set_visible(False)
    axes[0].set_ylabel("Overall per case (mean over seeds)")
    n_seeds = len(summary.seeds)
    suite, backend = _run_field(summary, "suite", "bench"), _run_field(summary, "backend", "")
    seeds = f"{n_seeds} seed{'s' if n_seeds != 1 else ''}"
    fig.suptitle(f"{suite}: Overall by case ({backend}, {seeds})", fontsize=12)
    fig.tight_layout()
    return fig


class IntervalBounds(Protocol):
    """What the figure reads of a run's intervals (``packlab.bench.summary.RunIntervals``)."""

    def bounds(self, policy: str, group: str, metric: str) -> tuple[float, float] | None: ...


#: A run's bootstrap intervals: a ``RunIntervals`` or summary.json's ``intervals`` object.
Intervals = IntervalBounds | Mapping[str, Any]


def overall_bounds(
    intervals: Intervals | None, policy: str, group: str
) -> tuple[float, float] | None:
    """The Overall interval of one method and group, or None (no intervals, none for that cell,
    or a malformed entry)."""
    if intervals is None:
        return None
    if isinstance(intervals, Mapping):
        row = intervals.get("policies", {}).get(policy, {})
        found = row.get("cells", {}).get(group, {}).get("overall") if row else None
    else:
        found = intervals.bounds(policy, group, "overall")
    if found is None or len(found) != 2:
        return None
    low, high = float(found[0]), float(found[1])
    return (low, high) if np.isfinite(low) and np.isfinite(high) and low <= high else None


def _group_bars(
    ax: Any, summary: RunSummary, intervals: Intervals | None, group: str, j: int, n: int
) -> int:
    """One group's bars (one per method) with their interval bars; returns how many methods
    got an interval."""
    policies = list(summary.policies)
    width = 0.8 / n
    offs = np.arange(len(policies)) - 0.4 + width * (j + 0.5)
    means, bounds = [], []
    for p in policies:
        cells = summary.table[p].get(group)
        cell = None if cells is None else cells.overall
        means.append(np.nan if cell is None or cell.mean is None else cell.mean)
        bounds.append(overall_bounds(intervals, p, group))
    is_avg = group == AVERAGE or n == 1
    ax.bar(
        offs,
        means,
        width * 0.92,
        color=[method_colour(p, policies) for p in policies],
        alpha=1.0 if is_avg else _GROUP_ALPHA.get(j, 0.5),
        edgecolor="#333333" if is_avg else "none",
        linewidth=0.6,
        label=group_title(group),
    )
    shown = [(i, b) for i, b in enumerate(bounds) if b is not None and not np.isnan(means[i])]
    if shown:
        ax.errorbar(
            offs[[i for i, _ in shown]],
            [means[i] for i, _ in shown],
            yerr=[
                [max(means[i] - low, 0.0) for i, (low, _) in shown],
                [max(high - means[i], 0.0) for i, (_, high) in shown],
            ],
            fmt="none",
            elinewidth=0.8,
            capsize=2,
            ecolor="#333333",
        )
    if is_avg:
        for i, (m, b) in enumerate(zip(means, bounds)):
            if not np.isnan(m):
                top = m if b is None else max(m, b[1])
                ax.text(offs[i], top + 0.02, f"{m:.3f}", ha="center", va="bottom", fontsize=8)
    return len(shown)


def average_overall_figure(summary: RunSummary, intervals: Intervals | None = None) -> Figure:
    """Bars of mean Overall per method: one per difficulty (light) and the average (solid).

    Error bars are the 95 % bootstrap interval over cases of each bar's mean (``intervals``: the
    run's ``RunIntervals`` or summary.json's ``intervals`` object); a bar without an interval
    (none given, or none for that cell) has no error bar: the spread over run seeds is not drawn,
    since it says nothing about how sure a mean over cases is. The average's value is printed
    above its bar.
    """
    policies, diffs = list(summary.policies), list(summary.difficulties)
    groups = [*diffs, AVERAGE] if len(diffs) > 1 else list(diffs)
    n = len(groups)
    fig = Figure(figsize=(max(6.5, 1.15 * len(policies) + 1.5), 4.2))
    ax = fig.subplots()
    with_bars = sum(_group_bars(ax, summary, intervals, g, j, n) for j, g in enumerate(groups))
    ax.set_xticks(np.arange(len(policies)))
    ax.set_xticklabels([display_name(p) for p in policies], fontsize=9)
    ax.set_ylim(0, 1.12)
    ax.set_ylabel("Overall (mean over cases and seeds)")
    ax.grid(axis="y", color="#DDDDDD", linewidth=0.7)
    ax.set_axisbelow(True)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)
    if n > 1:
        # Legend by group shade, drawn in neutral grey so it does not suggest one method.
        handles = [
            Patch(
                facecolor="#555555",
                alpha=1.0 if g == AVERAGE else _GROUP_ALPHA.get(j, 0.5),
                edgecolor="#333333" if g == AVERAGE else "none",
                label=group_title(g),
            )
            for j, g in enumerate(groups)
        ]
        ax.legend(handles=handles, ncol=n, fontsize=8, frameon=False, loc="upper left")
    bars_are = "bars: difficulties, then average; " if n > 1 else ""
    spread = "95 % bootstrap interval over cases" if with_bars else "no interval"
    suite = _run_field(summary, "suite", "bench")
    ax.set_title(f"{suite}: mean Overall per method ({bars_are}{spread})", fontsize=10)
    fig.tight_layout()
    return fig


def loss_curve_figure(log_path: str | os.PathLike[str], title: str = "SFT loss") -> Figure:
    """Training loss per logged step (and a moving average), and the validation loss where the
    run measured one, from an SFT run's loss_log.jsonl (other lines, e.g. play results, skipped)."""
    text = Path(log_path).read_text()
    rows = [json.loads(line) for line in text.splitlines() if line.strip()]
    train = [r for r in rows if "loss" in r]
    val = [r for r in rows if "eval_loss" in r]
    steps = [r["step"] for r in train]
    losses = [r["loss"] for r in train]
    fig = Figure(figsize=(6, 3.5), dpi=120)
    ax = fig.add_subplot()
    ax.plot(steps, losses, lw=0.8, alpha=0.5, label="training, per step")
    w = max(1, len(losses) // 20)
    if len(losses) >= 2 * w > 2:
        avg = [sum(losses[i - w + 1 : i + 1]) / w for i in range(w - 1, len(losses))]
        ax.plot(steps[w - 1 :], avg, lw=1.6, label=f"training, moving mean ({w})")
    if val:
        ax.plot([r["step"] for r in val], [r["eval_loss"] for r in val], "o-", label="validation")
    ax.set_xlabel("optimizer step")
    ax.set_ylabel("answer-token NLL")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return fig


def plot_loss_curve(
    log_path: str | os.PathLike[str], png_path: str | os.PathLike[str], title: str = "SFT loss"
) -> Path:
    """:func:`loss_curve_figure` written as a PNG (``packlab train sft`` writes loss_curve.png)."""
    return save_figure(loss_curve_figure(log_path, title), png_path, dpi=120)


__all__ = [
    "IntervalBounds",
    "Intervals",
    "average_overall_figure",
    "loss_curve_figure",
    "method_colour",
    "overall_bounds",
    "overall_distribution_figure",
    "plot_loss_curve",
    "save_figure",
]
