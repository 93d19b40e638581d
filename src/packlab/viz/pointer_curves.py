"""The learning-curve figure of a candidate-mode training log (``log.csv`` -> ``curves.png``);
the trainer calls it through its ``on_log`` hook (the vlm layer does not draw)."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def _column(rows: list[dict[str, str]], key: str) -> list[float]:
    return [float(r[key]) for r in rows if r.get(key) not in (None, "")]


def write_curves(log: Path, out: Path) -> None:
    """Left: training loss and held-out NLL against the marginal baseline. Right: held-out
    exact match against always-index-0, and the closed-loop Overall."""
    with open(log) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return
    steps = _column(rows, "step")
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    for key, label in (("train_loss", "train loss"), ("heldout_nll", "held-out NLL"),
                       ("marginal_nll", "marginal baseline")):  # fmt: skip
        if rows[0].get(key):
            a.plot(steps, _column(rows, key), label=label)
    a.set_xlabel("update")
    a.set_ylabel("answer NLL (nats)")
    a.legend()
    for key, label in (("heldout_match", "held-out match"), ("first_match", "index 0 match"),
                       ("loop_avg", "closed-loop Overall")):  # fmt: skip
        if rows[0].get(key):
            b.plot(steps, _column(rows, key), label=label, marker="." if "loop" in key else None)
    b.set_xlabel("update")
    b.set_ylim(0, 1)
    if b.get_lines():  # nothing to show without held-out states or closed-loop cases
        b.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
