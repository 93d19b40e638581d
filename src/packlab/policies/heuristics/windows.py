"""Moved to :mod:`packlab.policies.windows` (shared by the heuristics and
:mod:`packlab.policies.features`); this name re-exports it for existing imports."""

from packlab.policies.windows import (
    padded,
    side_neighbours,
    sliding,
    window_count_of_max,
    window_sum,
)

__all__ = ["padded", "side_neighbours", "sliding", "window_count_of_max", "window_sum"]
