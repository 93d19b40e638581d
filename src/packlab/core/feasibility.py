"""The one shared candidate search every heuristic (and the random/RL policies) scores.

A *candidate* is a (shown object, rotation, cell x, cell y) whose footprint lies on the container
floor grid. Its resting height z is paper Eq. 2, the maximum of the heightmap over the footprint,
computed for all (x, y) of one orientation by a single sliding-window maximum
(:func:`footprint_max`). Orientations that share a footprint (two equal
boxes, or rotation 1 of a square box) share that maximum, so a decision costs at most one window
max per distinct (fx, fy).

Candidates come in *scan order*: shown object, then rotation 0 before 1, then x, then y. That is
C order over the dense (k, 2, X, Y) action grid, which is what makes the flat arrays and the
dense masks two views of one set. Candidates are stored as consecutive *groups*, one per
(object, rotation) that fits, each a row-major (X - fx + 1, Y - fy + 1) grid; scorers work per
group on these 2-D grids (vectorised over cells) and concatenate, so no scorer loops over cells.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter1d

from packlab.core.types import Observation, ShownItem

#: Rotation values of an action; 1 is a 90 degree yaw that swaps l and w.
ROTATIONS = (0, 1)


def footprint_max(heightmap: np.ndarray, fx: int, fy: int) -> np.ndarray:
    """Max of ``heightmap`` over every (fx, fy)-cell window; shape (X - fx + 1, Y - fy + 1).

    Entry [x, y] is paper Eq. 2's drop height z for a footprint whose minimum cell is (x, y).
    Two separable 1-D running maxima (scipy's, a constant number of comparisons per cell
    whatever the footprint) keep it O(cells); each entry is the max of its whole window, so the
    result is exact. Empty when the footprint is larger than the map.
    """
    nx, ny = heightmap.shape
    if fx < 1 or fy < 1:
        raise ValueError(f"footprint must be at least one cell, got ({fx}, {fy})")
    if fx > nx or fy > ny:
        return np.zeros((max(nx - fx + 1, 0), max(ny - fy + 1, 0)), dtype=heightmap.dtype)
    # origin -(n // 2) makes entry i of the filter the max over cells [i, i + n); the entries
    # past X - fx (Y - fy) would reach beyond the map and are cut off.
    along_x = maximum_filter1d(heightmap, fx, axis=0, origin=-(fx // 2))[: nx - fx + 1]
    maxima: np.ndarray = maximum_filter1d(along_x, fy, axis=1, origin=-(fy // 2))[:, : ny - fy + 1]
    return maxima


def placement_height(heightmap: np.ndarray, x: int, y: int, fx: int, fy: int) -> int:
    """Eq. 2 for one footprint: max of the heightmap over cells [x, x+fx) x [y, y+fy)."""
    return int(heightmap[x : x + fx, y : y + fy].max())


def footprint_fits(shape: tuple[int, int], x: int, y: int, fx: int, fy: int) -> bool:
    """True when the footprint lies entirely on the container floor grid."""
    return 0 <= x and 0 <= y and x + fx <= shape[0] and y + fy <= shape[1]


@dataclass(frozen=True, slots=True)
class Orientation:
    """One (shown object, rotation) whose footprint fits the floor, with its Eq. 2 height grid."""

    object_index: int  # index into the shown buffer
    rotation: int  # 0 or 1
    fx: int  # footprint extent along x, cells
    fy: int  # footprint extent along y, cells
    height_mm: int  # box height (unchanged by a yaw)
    z: np.ndarray  # (X - fx + 1, Y - fy + 1) int32 mm: resting height of each minimum cell
    offset: int  # index of this group's first candidate in the flat arrays

    @property
    def size(self) -> int:
        return int(self.z.size)


@dataclass(frozen=True, slots=True)
class CandidateSet:
    """Every floor-fitting placement of every shown object at one step, in scan order.

    Flat arrays all have shape (n,) and list candidates in scan order (object, rotation, x, y).
    """

    heightmap: np.ndarray  # (X, Y) int32 mm, the state the candidates were computed on
    container_height_mm: int  # the rim: a candidate "fits in rim" when top <= this
    cell_mm: int  # horizontal cell size (mm), for areas and the SDF voxel size
    shown_sizes_mm: np.ndarray  # (k, 3) int64 mm: (l, w, h) of each shown object
    #: (k,) int64: each shown object's place among the shown ``internal_id``s sorted (integers
    #: before strings). Only the tie-break rule reads it, and only between identical boxes.
    shown_id_order: np.ndarray
    groups: tuple[Orientation, ...]  # in scan order; empty when nothing fits
    obj: np.ndarray  # (n,) int64 shown index
    rotation: np.ndarray  # (n,) int64 0/1
    x: np.ndarray  # (n,) int64 minimum cell along x
    y: np.ndarray  # (n,) int64 minimum cell along y
    z: np.ndarray  # (n,) int64 mm resting height (Eq. 2)
    top: np.ndarray  # (n,) int64 mm, z + box height
    fits_in_rim: np.ndarray  # (n,) bool, top <= container_height_mm
    fx: np.ndarray  # (n,) int64 footprint cells along x
    fy: np.ndarray  # (n,) int64 footprint cells along y
    h: np.ndarray  # (n,) int64 mm box height

    def __len__(self) -> int:
        return int(self.obj.size)

    @property
    def buffer_size(self) -> int:
        return int(self.shown_sizes_mm.shape[0])

    @property
    def grid_shape(self) -> tuple[int, int]:
        return (int(self.heightmap.shape[0]), int(self.heightmap.shape[1]))


def footprint_cells(item: ShownItem, rotation: int) -> tuple[int, int]:
    """(fx, fy) in cells of a shown item at a rotation; rotation 1 swaps l and w."""
    l_cells, w_cells, _ = item.size_cells
    return (w_cells, l_cells) if rotation == 1 else (l_cells, w_cells)


def id_order(shown: Sequence[ShownItem]) -> np.ndarray:
    """(k,) int64: the place of each item's ``internal_id`` when the shown ids are sorted.

    Ids are ints or strings (the reference's ``"obj_00000"``); ints sort before strings so a
    mix never compares across types. Equal ids (not valid in a case) keep the shown order.
    """
    ids = [item.internal_id for item in shown]
    by_id = sorted(range(len(ids)), key=lambda i: (isinstance(ids[i], str), ids[i]))
    order = np.empty(len(ids), dtype=np.int64)
    order[by_id] = np.arange(len(ids))
    return order


def search_candidates(
    heightmap: np.ndarray,
    shown: Sequence[ShownItem],
    container_height_mm: int,
    cell_mm: int = 25,
    first_only: bool = False,
) -> CandidateSet:
    """All floor-fitting candidates of ``shown`` on ``heightmap`` with Eq. 2 heights, scan order.

    ``heightmap`` is (X, Y) int mm. Objects whose footprint does not fit in a rotation simply
    contribute no group for it; the result may be empty (``len(...) == 0``). ``first_only``
    (the online protocol): only ``shown[0]`` gets candidates; the others stay in the set's
    buffer (``shown_sizes_mm``, the mask's rows) with none, so indices and shapes are those of
    the whole buffer.
    """
    hm = np.asarray(heightmap)
    nx, ny = hm.shape
    windows: dict[tuple[int, int], np.ndarray] = {}  # (fx, fy) -> Eq. 2 grid, shared
    groups: list[Orientation] = []
    offset = 0
    for k, item in enumerate(shown[:1] if first_only else shown):
        for rot in ROTATIONS:
            fx, fy = footprint_cells(item, rot)
            if fx < 1 or fy < 1 or fx > nx or fy > ny:
                continue
            if (fx, fy) not in windows:
                z = footprint_max(hm, fx, fy).astype(np.int64)
                z.flags.writeable = False  # shared by every orientation of this footprint
                windows[(fx, fy)] = z
            z = windows[(fx, fy)]
            groups.append(Orientation(k, rot, fx, fy, int(item.size_mm[2]), z, offset))
            offset += z.size
    return _flatten(hm, shown, container_height_mm, cell_mm, tuple(groups), offset)


def observation_candidates(observation: Observation) -> CandidateSet:
    """:func:`search_candidates` on a policy observation (heightmap, shown buffer, container);
    under the online protocol (``Observation.must_place_first``) only the first shown box's."""
    return search_candidates(
        observation.heightmap,
        observation.shown,
        observation.container.height_mm,
        observation.container.cell_xy_mm,
        first_only=observation.must_place_first,
    )


def fits_somewhere(heightmap: np.ndarray, item: ShownItem, container_height_mm: int) -> bool:
    """Whether ``item`` has a feasible placement: some cell of the candidate grid, in either
    yaw, whose footprint lies on the floor grid and whose top (Eq. 2 height + the box's height)
    stays within the rim. It is the in-rim action mask (:func:`action_mask` with
    ``in_rim_only``) of this one box, not empty. The online protocol ends an episode at the
    first box for which this is False ("fits nowhere"); support is not asked for (the boxes
    settle under physics, and the field's stability rules differ from paper to paper)."""
    cands = search_candidates(heightmap, [item], container_height_mm)
    return bool(action_mask(cands, in_rim_only=True).any())


def _flatten(
    hm: np.ndarray,
    shown: Sequence[ShownItem],
    container_height_mm: int,
    cell_mm: int,
    groups: tuple[Orientation, ...],
    n: int,
) -> CandidateSet:
    """Concatenate the per-orientation grids into the flat scan-order arrays."""
    names = ("obj", "rotation", "x", "y", "z", "fx", "fy", "h")
    fields = {name: np.empty(n, dtype=np.int64) for name in names}
    cells: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}  # grid shape -> (x, y)
    for g in groups:
        sl = slice(g.offset, g.offset + g.size)
        if g.z.shape not in cells:
            px, py = g.z.shape  # row-major = x then y, matching scan order
            cells[g.z.shape] = (np.repeat(np.arange(px), py), np.tile(np.arange(py), px))
        fields["obj"][sl] = g.object_index
        fields["rotation"][sl] = g.rotation
        fields["x"][sl], fields["y"][sl] = cells[g.z.shape]
        fields["z"][sl] = g.z.ravel()
        fields["fx"][sl] = g.fx
        fields["fy"][sl] = g.fy
        fields["h"][sl] = g.height_mm
    top = fields["z"] + fields["h"]
    fits_in_rim = top <= container_height_mm
    for arr in (*fields.values(), top, fits_in_rim):
        arr.flags.writeable = False  # scorers share these arrays; none may change them
    sizes = np.array([item.size_mm for item in shown], dtype=np.int64).reshape(len(shown), 3)
    return CandidateSet(
        heightmap=hm,
        container_height_mm=int(container_height_mm),
        cell_mm=int(cell_mm),
        shown_sizes_mm=sizes,
        shown_id_order=id_order(shown),
        groups=groups,
        top=top,
        fits_in_rim=fits_in_rim,
        **fields,
    )


def action_mask(cands: CandidateSet, in_rim_only: bool = False) -> np.ndarray:
    """Dense (k, 2, X, Y) bool mask over the action grid: True where a candidate exists.

    With ``in_rim_only`` only candidates whose top stays within the rim are True. Entry
    [object, rotation, x, y] matches ``Action(object, rotation, x, y)``.
    """
    nx, ny = cands.grid_shape
    mask = np.zeros((cands.buffer_size, len(ROTATIONS), nx, ny), dtype=bool)
    for g in cands.groups:
        px, py = g.z.shape
        allowed = g.z + g.height_mm <= cands.container_height_mm if in_rim_only else True
        mask[g.object_index, g.rotation, :px, :py] = allowed
    return mask


def scatter(cands: CandidateSet, values: np.ndarray, fill: float = 0) -> np.ndarray:
    """Spread per-candidate ``values`` (n,) onto the dense (k, 2, X, Y) grid, ``fill`` elsewhere."""
    nx, ny = cands.grid_shape
    out = np.full((cands.buffer_size, len(ROTATIONS), nx, ny), fill, dtype=np.asarray(values).dtype)
    out[cands.obj, cands.rotation, cands.x, cands.y] = values
    return out
