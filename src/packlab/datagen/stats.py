"""Distributions of generated cases (for ``packlab inspect-data`` and the distribution tests).

Pure over ``Case`` objects: the inspector loads cases from a dataset's episode shards, the tests
feed freshly generated ones, and both read the same numbers.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from packlab.cases import case_from_dict
from packlab.core.records import DatasetInfo
from packlab.core.types import Case
from packlab.datagen.format import EPISODES_DIR
from packlab.viz.distributions import cell_scatter_figure, histogram_figure
from packlab.viz.plots import save_figure


@dataclass(slots=True)
class Distribution:
    """Accumulated per-difficulty distributions (mutable while collecting, then read)."""

    episodes: int = 0
    objects_per_case: Counter = field(default_factory=Counter)
    layers: Counter = field(default_factory=Counter)
    layouts: Counter = field(default_factory=Counter)
    anchors: Counter = field(default_factory=Counter)
    base_sizes_cm: Counter = field(default_factory=Counter)
    buffer_sizes: Counter = field(default_factory=Counter)
    container_cm: list = field(default_factory=list)  # (X, Y, Z) per case
    stack_ratio: list = field(default_factory=list)  # stack height / container height per case
    heights_cm: Counter = field(default_factory=Counter)  # per object
    sides_cm: list = field(default_factory=list)  # (l, w) per object
    aspect: list = field(default_factory=list)  # per object, long / short footprint side
    rotated: int = 0
    objects: int = 0
    first_cell_frac: list = field(default_factory=list)  # first placement's cell / grid, per case

    def add(self, case: Case) -> None:
        g = case.generator
        self.episodes += 1
        self.objects_per_case[len(case.objects)] += 1
        self.layers[g.get("n_layers")] += 1
        self.layouts[g.get("layout")] += 1
        self.anchors[g.get("anchor")] += 1
        self.base_sizes_cm[tuple(g.get("base_size_cm", ()))] += 1
        self.buffer_sizes[case.buffer_size] += 1
        size_cm = tuple(v / 10 for v in case.container.size_mm)
        self.container_cm.append(size_cm)
        if "stack_height_cm" in g:
            self.stack_ratio.append(g["stack_height_cm"] / size_cm[2])
        for b in case.objects:
            l, w, h = (v / 10 for v in b.size_mm)
            self.heights_cm[h] += 1
            self.sides_cm.append((l, w))
            self.aspect.append(max(l, w) / min(l, w))
        self.objects += len(case.objects)
        self.rotated += sum(p.rotation for p in case.gt_plan or ())
        if "first_cell" in g:
            nx, ny = case.container.cells
            self.first_cell_frac.append((g["first_cell"][0] / nx, g["first_cell"][1] / ny))

    def summary(self) -> dict[str, Any]:
        def rng(values: list) -> dict[str, float] | None:
            if not values:
                return None
            a = np.asarray(values, dtype=np.float64)
            return {
                "min": round(float(a.min()), 4),
                "mean": round(float(a.mean()), 4),
                "max": round(float(a.max()), 4),
            }

        sides = np.asarray(self.sides_cm, dtype=np.float64).reshape(-1, 2)
        cont = np.asarray(self.container_cm, dtype=np.float64).reshape(-1, 3)
        return {
            "episodes": self.episodes,
            "objects": self.objects,
            "objects_per_case": dict(sorted(self.objects_per_case.items())),
            "layers": dict(sorted(self.layers.items(), key=lambda kv: str(kv[0]))),
            "layouts": dict(self.layouts),
            "buffer_size": dict(self.buffer_sizes),
            "container_x_cm": rng(cont[:, 0].tolist()),
            "container_y_cm": rng(cont[:, 1].tolist()),
            "container_z_cm": rng(cont[:, 2].tolist()),
            "base_sizes_cm": {
                "x".join(f"{v:g}" for v in k): n for k, n in sorted(self.base_sizes_cm.items())
            },
            "stack_height_ratio": rng(self.stack_ratio),
            "object_side_cm": rng(sides.ravel().tolist()),
            "object_height_cm": rng([h for h, n in self.heights_cm.items() for _ in range(n)]),
            "footprint_aspect": rng(self.aspect),
            "rotated_fraction": round(self.rotated / self.objects, 4) if self.objects else None,
            "anchors": dict(sorted(self.anchors.items(), key=lambda kv: str(kv[0]))),
        }


def collect(cases: Iterable[Case]) -> dict[str, Distribution]:
    """Distributions per difficulty (key ``""`` for cases without one)."""
    out: dict[str, Distribution] = {}
    for case in cases:
        out.setdefault(case.difficulty, Distribution()).add(case)
    return out


def dataset_cases(root: str | Path) -> Iterable[Case]:
    """Every kept case of a dataset directory, from its episode shards' ``case_json``."""
    for path in sorted(Path(root, EPISODES_DIR).glob("*.parquet")):
        for row, text in enumerate(
            pq.read_table(path, columns=["case_json"]).column(0).to_pylist(), 1
        ):
            yield case_from_dict(json.loads(text), str(path), row)


def format_report(info: DatasetInfo, dists: dict[str, Distribution]) -> str:
    """A plain-text report: counts and rejections from info.json, then distributions."""
    counts = info.counts
    lines = [
        (
            f"dataset {info.name} ({info.format_version}): "
            f"{counts.episodes} episodes, {counts.steps} steps, {counts.shards} shards"
        ),
        "",
        (
            f"{'difficulty':<10} {'requested':>9} {'episodes':>9} {'steps':>8} {'attempts':>9} "
            f"{'accept':>7}  rejections"
        ),
    ]
    by = counts.by_difficulty
    listed = info.generator_config.get("difficulties")
    order = [str(d) for d in listed] if isinstance(listed, list) and listed else list(by)
    for name in order:
        d = by[name]
        rate = d.acceptance_rate
        rej = ", ".join(f"{k}={v}" for k, v in d.rejections.items()) or "-"
        lines.append(
            f"{name:<10} {d.requested:>9} {d.episodes:>9} {d.steps:>8} {d.attempts:>9} "
            f"{'-' if rate is None else f'{rate:.3f}':>7}  {rej}"
        )
    for name in sorted(dists, key=lambda n: order.index(n) if n in order else len(order)):
        s = dists[name].summary()
        lines += ["", f"[{name or 'unlabelled'}] {s['episodes']} cases, {s['objects']} objects"]
        for key in (
            "objects_per_case",
            "layers",
            "layouts",
            "buffer_size",
            "base_sizes_cm",
            "anchors",
        ):
            lines.append(f"  {key:<20} " + "  ".join(f"{k}:{v}" for k, v in s[key].items()))
        for key in (
            "container_x_cm",
            "container_y_cm",
            "container_z_cm",
            "stack_height_ratio",
            "object_side_cm",
            "object_height_cm",
            "footprint_aspect",
        ):
            r = s[key]
            lines.append(
                f"  {key:<20} "
                + ("-" if r is None else f"min {r['min']:g}  mean {r['mean']:g}  max {r['max']:g}")
            )
        lines.append(f"  {'rotated_fraction':<20} {s['rotated_fraction']}")
    return "\n".join(lines)


#: Histogram panels of ``save_histograms``: (title, values of one group's ``Distribution``).
_HISTOGRAMS = (
    ("objects per case", lambda d: [k for k, n in d.objects_per_case.items() for _ in range(n)]),
    ("object height (cm)", lambda d: [k for k, n in d.heights_cm.items() for _ in range(n)]),
    ("object side (cm)", lambda d: [v for lw in d.sides_cm for v in lw]),
    ("footprint aspect", lambda d: d.aspect),
    ("stack height / container height", lambda d: d.stack_ratio),
)


def save_histograms(dists: dict[str, Distribution], out_dir: str | Path) -> list[Path]:
    """PNG histograms (``packlab.viz.distributions``) of the main distributions.

    Returns the files written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for title, values in _HISTOGRAMS:
        fig = histogram_figure(title, {name: values(d) for name, d in dists.items()})
        name = title.split(" (")[0].replace(" / ", "_over_").replace(" ", "_")
        written.append(save_figure(fig, out / f"{name}.png", dpi=100))
    points = {name: np.asarray(d.first_cell_frac) for name, d in dists.items() if d.first_cell_frac}
    fig = cell_scatter_figure("first placement (cell / grid)", points)
    written.append(save_figure(fig, out / "first_anchor.png", dpi=100))
    return written
