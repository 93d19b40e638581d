"""The candidate mode's context: a compact text state of the current step and an index answer.

The free mode (:mod:`.render`) shows a heightmap image and asks for a JSON placement. Candidate
mode lists K placements from the teacher-free proposer (:mod:`packlab.policies.candidates`) and
the answer is one index, so every answer that parses is a valid action. Its context is text only
and holds the current step only, a few hundred tokens:

- a system turn, fixed for a container, so a runtime can cache it: the task, the container, and
  a legend of the fields below (:func:`system_text`);
- one user turn per step (:func:`state_text`)::

      Step 5, 17 left.
      Map 4:
      99740000000000
      ...
      Boxes: 0:8x6x20 1:4x4x12 ...
      Places:
      0: b1 r0 x0 y12 z0 s10 f5 v0
      ...

  **Map**: the heightmap max-pooled over blocks of B x B cells (``Map B:``), one line per block
  row along y (y grows downwards, as in the free mode's image), one digit per block along x.
  The digit is the block's highest surface in ninths of the rim height, rounded up: 0 is empty
  floor, 9 is within the top ninth or above the rim. B is the smallest number of cells that
  keeps both sides at most :attr:`CompactOptions.map_side` blocks. With ``rle`` a run of
  :data:`RUN_MIN` or more equal digits is written ``d*n`` and runs are separated by spaces
  (measured longer than plain digits on bench states, so off by default).
  **Boxes**: ``index:l x w x h`` for each shown box, l and w in cells at rotation 0, h in cm.
  **Places**: ``n: b<box> r<rotation> x<x> y<y> z<resting height> s<support> f<flush>
  v<mean gap under it>``: x, y in cells, z and v in cm (rounded), support and flushness in
  tenths (half up); the fields of :class:`packlab.policies.candidates.Candidate` (the top is
  z plus the box's h, so it is left out).
- the answer: the index alone (``"3"``), :func:`answer_text`; :func:`parse_choice` maps it back to
  exactly the listed placement.

Part of the prompt format: a change to any text here bumps
:data:`packlab.vlm.prompt.render.PROMPT_VERSION`. Pure: no torch, no I/O.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from packlab.core.types import Action, Container, Observation, ShownItem, Unparsable
from packlab.policies.candidates import Candidate

#: Map digits: 0 = empty floor, 1..9 = ninths of the rim height (rounded up, 9 also above it).
LEVELS = 9
#: Shortest run of equal digits written ``d*n`` when ``rle`` is on.
RUN_MIN = 4
#: Longest candidate answer read (characters, whitespace included): an index has a few digits.
MAX_CHOICE_CHARS = 64

_INDEX = re.compile(r"\s*([0-9]{1,4})\s*")
_THINK_CLOSE = re.compile(r"(?s:.*)</think>", re.IGNORECASE)


@dataclass(frozen=True, slots=True)
class CompactOptions:
    """Map resolution (at most ``map_side`` blocks per side) and run-length encoding."""

    map_side: int = 8
    rle: bool = False

    def __post_init__(self) -> None:
        side = self.map_side
        if isinstance(side, bool) or not isinstance(side, int) or side < 1:
            raise ValueError(f"CompactOptions.map_side = {side!r}: must be a whole number >= 1")


def _cm(mm: int) -> int:
    return round(mm / 10)


def _tenths(pct: int) -> int:
    """A percentage in tenths, half up (one or two digits instead of up to three)."""
    return (pct + 5) // 10


def block_size(container: Container, map_side: int) -> int:
    """Cells per map block side: the smallest B with both sides at most ``map_side`` blocks."""
    nx, ny = container.cells
    return max(1, -(-max(nx, ny) // map_side))


def height_levels(heightmap: np.ndarray, container: Container, block: int) -> np.ndarray:
    """(ceil(X / B), ceil(Y / B)) int levels 0..9: each block's max, in ninths of the rim."""
    hm = np.asarray(heightmap, dtype=np.int64)
    nx, ny = hm.shape
    bx, by = -(-nx // block), -(-ny // block)
    padded = np.zeros((bx * block, by * block), dtype=np.int64)
    padded[:nx, :ny] = hm  # edge blocks hold fewer cells; zeros never raise a max above 0
    pooled = padded.reshape(bx, block, by, block).max(axis=(1, 3))
    levels = -(-pooled * LEVELS // max(container.height_mm, 1))
    return np.clip(levels, 0, LEVELS)


def _rle(digits: str) -> str:
    runs = [m.group(0) for m in re.finditer(r"(\d)\1*", digits)]
    out: list[str] = []
    for run in runs:
        if len(run) >= RUN_MIN:
            out.append(f"{run[0]}*{len(run)}")
        elif out and "*" not in out[-1]:
            out[-1] += run  # short runs stay plain digits, merged with plain neighbours
        else:
            out.append(run)
    return " ".join(out)


def map_lines(levels: np.ndarray, rle: bool = False) -> list[str]:
    """One line per block row (fixed y), one digit per block along x."""
    rows = ["".join(str(int(v)) for v in levels[:, j]) for j in range(levels.shape[1])]
    return [_rle(r) for r in rows] if rle else rows


def boxes_line(shown: Sequence[ShownItem]) -> str:
    items = sorted(shown, key=lambda s: s.shown_index)
    return "Boxes: " + " ".join(
        f"{s.shown_index}:{s.size_cells[0]}x{s.size_cells[1]}x{_cm(s.size_mm[2])}" for s in items
    )


def candidate_line(c: Candidate) -> str:
    """One listed placement: its index, then the fields of the legend."""
    return (
        f"{c.index}: b{c.object_index} r{c.rotation} x{c.x} y{c.y} z{_cm(c.z_mm)} "
        f"s{_tenths(c.support_pct)} f{_tenths(c.flush_pct)} v{_cm(c.void_mm)}"
    )


def system_text(
    container: Container, options: CompactOptions = CompactOptions(), image_map: bool = False
) -> str:
    """The fixed instructions for one container (the same every step: cacheable); with
    ``image_map`` the map legend describes the heightmap image instead of the digit map."""
    nx, ny = container.cells
    block = block_size(container, options.map_side)
    task = (
        "You pack boxes into an open-top container. Each step lists possible placements; "
        "answer with the number of the best one only."
    )
    grid = (
        f"Container: {nx} x {ny} cells of {container.cell_xy_mm} mm, rim "
        f"{_cm(container.height_mm)} cm."
    )
    map_legend = (
        f"Map: one line per {block}-cell band along y, one digit per {block}-cell block along x: "
        "its highest surface in ninths of the rim (0 floor, 9 rim)."
    )
    if image_map:
        map_legend = (
            "Image: the heightmap seen from above, x to the right, y down; black is the floor, "
            "white the rim height (and the walls)."
        )
    boxes = "Boxes: index:l x w x h (l along x, w along y, in cells; h in cm)."
    places = (
        "Places: n: b box, r rotation (1 swaps l and w), x y its minimum cell, z resting height "
        "(cm), s tenths of its base supported, f tenths of its sides flush, v mean gap below (cm)."
    )
    lines = (task, grid, map_legend, boxes, places)
    return "\n".join(lines)


def state_text(
    observation: Observation,
    candidates: Sequence[Candidate],
    options: CompactOptions = CompactOptions(),
    show_map: bool = True,
) -> str:
    """The user turn of one step (module docstring); without the map lines when ``show_map`` is
    off (the heightmap is then shown as an image, :mod:`packlab.vlm.candidate.image`)."""
    block = block_size(observation.container, options.map_side)
    levels = height_levels(observation.heightmap, observation.container, block)
    shown_map = [f"Map {block}:", *map_lines(levels, options.rle)] if show_map else []
    lines = [
        f"Step {observation.step_index + 1}"
        + ("." if observation.remaining is None else f", {observation.remaining} left."),
        *shown_map,
        boxes_line(observation.shown),
        "Places:" if candidates else "Places: none fits.",
        *(candidate_line(c) for c in candidates),
    ]
    return "\n".join(lines)


def candidate_messages(
    observation: Observation,
    candidates: Sequence[Candidate],
    options: CompactOptions = CompactOptions(),
) -> list[dict[str, Any]]:
    """[system, user] chat messages (text entries only) for one step; the answer comes next."""
    return [
        {
            "role": "system",
            "content": [{"type": "text", "text": system_text(observation.container, options)}],
        },
        {
            "role": "user",
            "content": [{"type": "text", "text": state_text(observation, candidates, options)}],
        },
    ]


def answer_text(candidate: Candidate) -> str:
    """The exact assistant target for a listed placement: its index."""
    return str(candidate.index)


def parse_choice(text: str, candidates: Sequence[Candidate]) -> Action | Unparsable:
    """The listed placement an answer names, or an :class:`Unparsable` saying why not.

    Accepted: the index in decimal digits with optional surrounding whitespace, after an optional
    ``...</think>`` block (only the text after the last one is read). Nothing else: a candidate
    answer is generated or scored as exactly the index, so anything more is not one.
    """
    if not isinstance(text, str):
        return Unparsable(text="", error=f"expected text, got {type(text).__name__}")
    kept = text[:MAX_CHOICE_CHARS]
    if len(text) > MAX_CHOICE_CHARS:
        return Unparsable(kept, f"answer too long: {len(text):,} characters")
    last = _THINK_CLOSE.match(text)
    body = text[last.end() :] if last else text
    m = _INDEX.fullmatch(body)
    n = len(candidates)
    if m is None:
        return Unparsable(kept, f"expected a placement number 0..{n - 1}" if n else "no places")
    index = int(m.group(1))
    if index >= n:
        return Unparsable(
            kept, f"placement {index} is not listed (0..{n - 1})" if n else "no places"
        )
    return candidates[index].action
