"""A suite's own statistics per difficulty (``packlab bench --describe``), pure over cases.

The paper's Table 1 gives, per level, the object and layer ranges and about 905 packing steps in
all; this prints the same quantities measured on the actual case file, so a suite can be checked
against the published description at a glance.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from packlab.core.choices import Difficulty, choices
from packlab.core.types import Case


def _layers(case: Case) -> int | None:
    """Layers of a case: from its plan (distinct layer indices), else the generator's note."""
    if case.gt_plan:
        return len({p.layer_index for p in case.gt_plan})
    n = case.generator.get("n_layers") if case.generator else None
    return int(n) if isinstance(n, int) else None


@dataclass(frozen=True, slots=True)
class Range:
    """min / mean / max of one quantity over the cases of a group."""

    low: float
    mean: float
    high: float

    @staticmethod
    def of(values: Sequence[float]) -> Range | None:
        if not values:
            return None
        return Range(min(values), sum(values) / len(values), max(values))

    def text(self, digits: int = 1) -> str:
        fmt = (
            (lambda v: f"{v:g}")
            if digits == 0
            else (lambda v: f"{v:.{digits}f}".rstrip("0").rstrip("."))
        )
        return f"{fmt(self.low)}-{fmt(self.high)} (mean {self.mean:.{max(digits, 1)}f})"


@dataclass(frozen=True, slots=True)
class GroupStats:
    """Statistics of the cases of one difficulty (or of the whole suite)."""

    name: str
    n_cases: int
    buffer_sizes: tuple[int, ...]
    objects: Range | None  # None for a group of no cases
    layers: Range | None
    steps: int  # packing steps: one per object
    container_cm: tuple[tuple[float, float, float], ...]  # distinct container sizes, sorted
    fill_ratio: Range | None  # object volume / container volume

    def to_dict(self) -> dict:
        def r(x: Range | None) -> dict | None:
            return None if x is None else {"min": x.low, "mean": x.mean, "max": x.high}

        return {
            "cases": self.n_cases,
            "buffer_sizes": list(self.buffer_sizes),
            "objects": r(self.objects),
            "layers": r(self.layers),
            "steps": self.steps,
            "container_cm": [list(c) for c in self.container_cm],
            "fill_ratio": r(self.fill_ratio),
        }


def group_stats(name: str, cases: Sequence[Case]) -> GroupStats:
    layers = [n for n in (_layers(c) for c in cases) if n is not None]
    containers = sorted(
        {(x / 10, y / 10, z / 10) for x, y, z in (c.container.size_mm for c in cases)}
    )
    return GroupStats(
        name=name,
        n_cases=len(cases),
        buffer_sizes=tuple(sorted({c.buffer_size for c in cases})),
        objects=Range.of([len(c.objects) for c in cases]),
        layers=Range.of(layers) if len(layers) == len(cases) else None,
        steps=sum(len(c.objects) for c in cases),
        container_cm=tuple(containers),
        fill_ratio=Range.of([c.total_volume_mm3 / c.container.volume_mm3 for c in cases]),
    )


def difficulty_order(names: Sequence[str]) -> list[str]:
    """easy, medium, hard first (the paper's order), then any other label alphabetically."""
    known = choices(Difficulty)
    return [n for n in known if n in names] + sorted(n for n in set(names) if n not in known)


def describe_cases(cases: Sequence[Case]) -> list[GroupStats]:
    """Per difficulty, then ``all``."""
    groups = difficulty_order([c.difficulty for c in cases])
    out = [group_stats(g, [c for c in cases if c.difficulty == g]) for g in groups]
    return out + [group_stats("all", list(cases))]


def _containers_text(sizes: tuple[tuple[float, float, float], ...]) -> str:
    """Per-axis ranges: container sizes are jittered per case, so a list would be long."""
    if len(sizes) == 1:
        return "x".join(f"{v:g}" for v in sizes[0])
    axes = zip(*sizes)
    return " x ".join(f"{min(a):g}-{max(a):g}" for a in axes) + f" ({len(sizes)} sizes)"


def format_description(label: str, stats: Sequence[GroupStats]) -> str:
    """A plain-text table of the statistics, one row per group."""
    header = (
        f"{'difficulty':<10} {'cases':>5} {'buffer':>6}  {'objects/case':<22} {'layers':<20} "
        f"{'steps':>5}  {'fill':<22} containers (cm)"
    )
    lines = [f"{label}", header, "-" * len(header)]
    for s in stats:
        buf = ",".join(map(str, s.buffer_sizes))
        layers = s.layers.text() if s.layers else "-"
        objects = s.objects.text() if s.objects else "-"
        fill = s.fill_ratio.text(2) if s.fill_ratio else "-"
        lines.append(
            f"{s.name:<10} {s.n_cases:>5} {buf:>6}  {objects:<22} {layers:<20} "
            f"{s.steps:>5}  "
            f"{fill:<22} {_containers_text(s.container_cm)}"
        )
    return "\n".join(lines)


__all__ = [
    "GroupStats",
    "Range",
    "describe_cases",
    "difficulty_order",
    "format_description",
    "group_stats",
]
