"""What an RL agent sees: fixed-size arrays made from a packing :class:`Observation` (pure).

Both agents see the same three arrays, so one network family serves both, across every
container size and buffer size the levels use:

- ``heightmap``: (1, G, G) float32, the container's heightmap resampled to a G x G grid
  (nearest cell) in units of the container height. Resampling instead of padding keeps a 20 x 20
  easy container and a 57 x 57 hard one equally visible to a small CNN; exact geometry goes in
  the item rows below.
- ``globals``: (:data:`N_GLOBALS`,) float32 scalars of the state (:func:`global_row`).
- ``items``: (N, :data:`N_ITEM_FEATURES`) float32, one row per choosable item, zero rows for
  padding; column 0 is 1 for a real item, which is also the action mask. An item is a placement
  (object, rotation, x, y) with its geometry (:func:`placement_row`):

  - ``irbpp``: the K placements listed by the shared proposer
    (:func:`packlab.policies.candidates.propose`): the IR-BPP-style candidate action space;
  - ``tapnet``: one per shown object, placed by the spec's rule (:func:`object_placements`: the
    proposer's first listing of that object, or DBLF's rule for it alone): the TAP-Net-style
    object-choice action space.

The action is the row index. Rows list items in the proposer's order or the shown order (shuffled
every step by the episode); the networks score each row with shared weights, so an agent cannot
learn an index, only what a row's geometry is worth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from packlab.core.choices import (
    DEFAULT_TAPNET_PLACEMENT,
    RLAgent,
    TapnetPlacement,
    require_choice,
)
from packlab.core.feasibility import CandidateSet, observation_candidates
from packlab.core.types import Action, Observation
from packlab.policies.candidates import (
    STUDENT_K,
    Candidate,
    ProposerConfig,
    placement_index,
    propose_from,
)
from packlab.policies.features import (
    flush_cells_at,
    side_cells,
    space_under_at,
    support_cells_at,
    walled,
)
from packlab.policies.heuristics.select import object_rank
from packlab.policies.level_fit import N_FEATURES as N_LEVEL_FIT
from packlab.policies.level_fit import Levels, level_fit

#: Side of the resampled heightmap.
GRID = 32
#: Columns of an item row: the placement's own geometry (:func:`placement_row`), then its level
#: fit (:mod:`packlab.policies.level_fit`: how it leaves its level for the other shown boxes).
N_PLACEMENT_FEATURES = 16
N_ITEM_FEATURES = N_PLACEMENT_FEATURES + N_LEVEL_FIT
#: What the item rows hold, recorded on every agent card: 1 = placement geometry only (agents
#: trained before the level fit), 2 = geometry and level fit. An agent plays only the version it
#: was trained on.
FEATURES_VERSION = 2
#: Entries of the globals row (see :func:`global_row`).
N_GLOBALS = 8
#: Scale for counts (steps, objects): the hard level has at most 32 objects.
COUNT_SCALE = 32.0
#: Scale for container sides in cells and buffer sizes.
SIDE_SCALE = 64.0
BUFFER_SCALE = 10.0
#: Upper clip of every feature, so the spaces are bounded (a box can stick out over the rim).
FEATURE_MAX = 4.0
#: The largest buffer of any level: the tapnet item count.
MAX_BUFFER = 10


@dataclass(frozen=True, slots=True)
class FeatureSpec:
    """Which action space, how many item rows (``n_items``) and, for tapnet, the rule that
    places the chosen object (``placement``; irbpp's rows are the proposer's anyway)."""

    agent: RLAgent
    n_items: int
    placement: TapnetPlacement = DEFAULT_TAPNET_PLACEMENT

    def __post_init__(self) -> None:
        require_choice(self.agent, RLAgent, "agent")
        require_choice(self.placement, TapnetPlacement, "placement")
        if isinstance(self.n_items, bool) or not isinstance(self.n_items, int) or self.n_items < 1:
            raise ValueError(f"FeatureSpec.n_items = {self.n_items!r}: must be an int >= 1")

    @classmethod
    def default(
        cls,
        agent: RLAgent,
        k: int = STUDENT_K,
        placement: TapnetPlacement = DEFAULT_TAPNET_PLACEMENT,
    ) -> FeatureSpec:
        """irbpp: ``k`` listed placements; tapnet: one row per buffer slot of the largest level."""
        return cls(agent, k if agent == "irbpp" else MAX_BUFFER, placement)


@dataclass(frozen=True, slots=True)
class Encoded:
    """One observation as arrays, and the action each real item row stands for."""

    arrays: dict[str, np.ndarray]  # heightmap (1, G, G), globals (N_GLOBALS,), items (N, F)
    actions: tuple[Action, ...]  # one per real row, rows 0 .. len - 1
    #: The flat index into the observation's candidate set of each real row's placement.
    rows: tuple[int, ...] = ()

    @property
    def mask(self) -> np.ndarray:
        """(N,) bool: rows an agent may choose."""
        return self.arrays["items"][:, 0] > 0


def resampled_heightmap(heightmap: np.ndarray, height_mm: int, grid: int = GRID) -> np.ndarray:
    """(1, grid, grid) float32: nearest-cell resample in container heights."""
    nx, ny = heightmap.shape
    xs = np.minimum(((np.arange(grid) + 0.5) * nx / grid).astype(np.int64), nx - 1)
    ys = np.minimum(((np.arange(grid) + 0.5) * ny / grid).astype(np.int64), ny - 1)
    out = heightmap[np.ix_(xs, ys)].astype(np.float32) / float(height_mm)
    return np.clip(out, 0.0, FEATURE_MAX)[None]


def global_row(observation: Observation) -> np.ndarray:
    """(N_GLOBALS,) float32: step, remaining objects, peak and mean height, container sides,
    container height (m), shown count."""
    hm = observation.heightmap
    height = float(observation.container.height_mm)
    nx, ny = observation.container.cells
    row = [
        observation.step_index / COUNT_SCALE,
        # Hidden (--remaining hidden): the least it can be, the shown objects.
        observation.remaining_at_least() / COUNT_SCALE,
        float(hm.max()) / height,
        float(hm.mean()) / height,
        nx / SIDE_SCALE,
        ny / SIDE_SCALE,
        height / 1000.0,
        len(observation.shown) / BUFFER_SCALE,
    ]
    return np.clip(np.asarray(row, dtype=np.float32), 0.0, FEATURE_MAX)


def placement_row(cands: CandidateSet, walls: np.ndarray, index: int, rank: int) -> np.ndarray:
    """(N_ITEM_FEATURES,) float32 for candidate ``index``; ``walls`` is the heightmap inside a
    ring of walls at the rim's height (:func:`~packlab.policies.features.walled`, made once per
    state); ``rank`` is the object's place when the shown objects are sorted larger first
    (:func:`object_rank`).

    Columns: valid, x0/X, y0/Y, x1/X, y1/Y, footprint area share, h/H, z/H, top/H, over rim,
    support share (footprint cells at z), flush share (side cells against a wall or a column
    above z), mean void under the box / H, box volume share of the container, rotation,
    size rank / buffer size. Support, flushness and the void are the shared placement features
    (:mod:`packlab.policies.features`).
    """
    hm = cands.heightmap
    nx, ny = hm.shape
    height = float(cands.container_height_mm)
    x, y = int(cands.x[index]), int(cands.y[index])
    fx, fy = int(cands.fx[index]), int(cands.fy[index])
    z, h = int(cands.z[index]), int(cands.h[index])
    area = fx * fy
    row = [
        1.0,
        x / nx,
        y / ny,
        (x + fx) / nx,
        (y + fy) / ny,
        area / (nx * ny),
        h / height,
        z / height,
        (z + h) / height,
        float(z + h > cands.container_height_mm),
        support_cells_at(hm, x, y, fx, fy, z) / area,
        flush_cells_at(walls, x, y, fx, fy, z) / side_cells(fx, fy),
        float(space_under_at(hm, x, y, fx, fy, z)) / area / height,
        area * h / (nx * ny * height),
        float(cands.rotation[index]),
        rank / BUFFER_SCALE,
    ]
    return np.clip(np.asarray(row, dtype=np.float32), 0.0, FEATURE_MAX)


def item_row(
    observation: Observation,
    cands: CandidateSet,
    walls: np.ndarray,
    index: int,
    rank: int,
    levels: Levels | None = None,
) -> np.ndarray:
    """(N_ITEM_FEATURES,) float32: the whole item row of candidate ``index`` (its geometry,
    :func:`placement_row`, then its level fit, :func:`level_fit_at`)."""
    return np.concatenate(
        [placement_row(cands, walls, index, rank), level_fit_at(observation, cands, index, levels)]
    )


def level_fit_at(
    observation: Observation, cands: CandidateSet, index: int, levels: Levels | None = None
) -> np.ndarray:
    """(N_LEVEL_FIT,) float32: :func:`packlab.policies.level_fit.level_fit` of candidate
    ``index`` (clipped like every column); ``levels``: the state's, shared by its rows."""
    x, y, z = int(cands.x[index]), int(cands.y[index]), int(cands.z[index])
    fx, fy, h = int(cands.fx[index]), int(cands.fy[index]), int(cands.h[index])
    placement = Candidate(0, int(cands.obj[index]), int(cands.rotation[index]), x, y, fx, fy,
                          z, z + h, 0, 0, 0)  # fmt: skip
    row = level_fit(cands.heightmap, observation.shown, placement, levels)
    return np.clip(row, 0.0, FEATURE_MAX)


def rule_placement(cands: CandidateSet, object_index: int) -> int | None:
    """DBLF's choice for one shown object: lowest z, then x, then y, rotation 0 before 1, among
    its placements within the rim (else its lowest-top ones); None when it fits nowhere."""
    own = np.flatnonzero(cands.obj == object_index)
    if own.size == 0:
        return None
    in_rim = own[cands.fits_in_rim[own]]
    pool = in_rim if in_rim.size else own[cands.top[own] == cands.top[own].min()]
    # lexsort is stable and the pool is in scan order, so rotation 0 wins a full tie.
    return int(pool[np.lexsort((cands.y[pool], cands.x[pool], cands.z[pool]))[0]])


#: Placements the proposer lists when it places tapnet's objects: enough that every shown
#: object of the largest buffer gets its own first listing.
OBJECT_LISTING_K = 64


def object_placements(
    cands: CandidateSet, n_objects: int, placement: TapnetPlacement
) -> list[int | None]:
    """Flat index of the placement ``placement`` gives each of the first ``n_objects`` shown
    objects (None where it fits nowhere): ``proposer``, the proposer's first listing of the
    object (DBLF's rule where the proposer lists none of it); ``dblf``, :func:`rule_placement`."""
    first: dict[int, int | None] = {}
    if placement == "proposer":
        for c in propose_from(cands, ProposerConfig(k=OBJECT_LISTING_K)):
            if c.object_index not in first:
                first[c.object_index] = placement_index(cands, c.object_index, c.rotation, c.x, c.y)
    return [
        first[j] if first.get(j) is not None else rule_placement(cands, j) for j in range(n_objects)
    ]


def listed_indices(cands: CandidateSet, spec: FeatureSpec) -> list[int]:
    """Flat candidate indices of the item rows, in row order."""
    if spec.agent == "tapnet":
        n = min(cands.buffer_size, spec.n_items)
        return [i for i in object_placements(cands, n, spec.placement) if i is not None]
    listed = propose_from(cands, ProposerConfig(k=spec.n_items))
    out = [placement_index(cands, c.object_index, c.rotation, c.x, c.y) for c in listed]
    return [i for i in out if i is not None]


def encode(
    observation: Observation, spec: FeatureSpec, cands: CandidateSet | None = None
) -> Encoded:
    """The arrays an agent sees for ``observation`` and the actions of its item rows
    (``cands``: the observation's candidate set when the caller already has it)."""
    cands = observation_candidates(observation) if cands is None else cands
    ranks: np.ndarray | list[int] = (
        object_rank(cands.shown_sizes_mm, cands.shown_id_order) if cands.buffer_size else []
    )
    items = np.zeros((spec.n_items, N_ITEM_FEATURES), dtype=np.float32)
    actions = []
    walls = walled(cands.heightmap, cands.container_height_mm)
    levels = Levels(cands.heightmap)
    rows = listed_indices(cands, spec)
    for row, i in enumerate(rows):
        rank = int(ranks[int(cands.obj[i])])
        items[row] = item_row(observation, cands, walls, i, rank, levels)
        actions.append(
            Action(int(cands.obj[i]), int(cands.rotation[i]), int(cands.x[i]), int(cands.y[i]))
        )
    arrays = {
        "heightmap": resampled_heightmap(observation.heightmap, observation.container.height_mm),
        "globals": global_row(observation),
        "items": items,
    }
    return Encoded(arrays, tuple(actions), tuple(rows))
