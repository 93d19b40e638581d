"""The learning-curve figure of an RL training log (``log.csv`` -> ``curves.png``); the trainer
calls it through its ``on_log`` hook (the rl layer does not draw)."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

LEVEL_STYLES = (("easy", ":"), ("medium", "--"), ("hard", "-."), ("avg", "-"))


def _column(rows: list[dict[str, str]], key: str) -> list[float]:
    return [float(r[key]) if r.get(key) not in (None, "") else float("nan") for r in rows]


def write_rl_curves(
    log: Path, out: Path, agent: str = "", references: dict[str, float] | None = None
) -> None:
    """Mean training return (= Overall under the default reward) and the held-out Overall per
    level against env steps; ``references`` (name -> held-out average Overall of another
    policy on the same cases) are drawn as horizontal lines."""
    with open(log) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return
    steps = _column(rows, "env_steps")
    fig, ax = plt.subplots(figsize=(7.4 if references else 6.4, 3.8))
    ax.plot(steps, _column(rows, "train_return"), color="0.6", label="training return")
    for level, style in LEVEL_STYLES:
        ax.plot(steps, _column(rows, level), style, label=f"held-out {level}")
    label_y = 2.0
    for n, (name, value) in enumerate(sorted((references or {}).items(), key=lambda kv: -kv[1])):
        label_y = min(value, label_y - 0.035)  # labels of close values stack instead of overlap
        ax.axhline(value, color=f"C{n + 4}", lw=0.8, ls=(0, (1, 2)))
        ax.annotate(f"{name} {value:.3f}", (1.0, label_y), xycoords=("axes fraction", "data"),
                    xytext=(3, 0), textcoords="offset points", va="center", fontsize=7,
                    color=f"C{n + 4}")  # fmt: skip
    ax.set_xlabel("env steps")
    ax.set_ylabel("Overall")
    ax.set_ylim(0, 1)
    ax.set_title(f"{agent} (MaskablePPO, geometric backend)" if agent else "MaskablePPO")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
