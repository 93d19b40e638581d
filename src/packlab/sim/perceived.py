"""Perceived mode in the episode loop: what the robot sees and how it reads it.

The perceiver (``packlab.sim.replan.Perceiver``) looks at the true scene; from its
``Perception`` this module builds the buffer the policy is shown (perceived sizes under fresh
ids), maps the policy's rotation onto the box, gives the grasped box's pose-estimate error to
noisy execution, and predicts the heightmap a placement should leave (the re-plan test's
reference). The loop itself is ``packlab.sim.episode``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from packlab.core.types import Case, ShownItem
from packlab.sim.buffer import MEASURED_SIDE_SLACK_MM, size_cells
from packlab.sim.execution import NO_GRASP_ERROR
from packlab.sim.replan import Perceiver, Perception, Scene, predict_heightmap


def perceive(
    perceiver: Perceiver,
    case: Case,
    heightmap: np.ndarray,
    poses: tuple[np.ndarray, np.ndarray],
    shown: Sequence[int],
    rng: np.random.Generator,
) -> Perception:
    """Look at the scene: ``heightmap`` the exact one, ``poses`` the backend's (centres mm,
    quaternions wxyz) of every box, ``shown`` the case indices in the buffer, in shown order."""
    positions, quaternions = poses
    scene = Scene(
        container=case.container,
        sizes_mm=np.array([b.size_mm for b in case.objects], dtype=np.int64),
        positions_mm=positions,
        quaternions=quaternions,
        heightmap=heightmap,
        shown=tuple(shown),
    )
    perception = perceiver(scene, rng)
    listed = perception.listed_boxes(len(shown))
    if len(perception.sizes_mm) != len(listed):
        raise ValueError(
            f"perceiver returned {len(perception.sizes_mm)} sizes for {len(listed)} listed boxes"
        )
    if any(not 0 <= p < len(shown) for p in listed):
        raise ValueError(f"perceiver picks {listed} outside the {len(shown)} buffered boxes")
    return perception


def seen_items(
    shown: tuple[ShownItem, ...], perception: Perception, case: Case, first_id: int
) -> tuple[ShownItem, ...]:
    """The buffer as the policy is shown it in perceived mode: ``shown`` the listed boxes' exact
    items (``Perception.listed_boxes``), given the perceived sizes (cells rounded up less
    :data:`~packlab.sim.buffer.MEASURED_SIDE_SLACK_MM`) under ids ``seen-<n>`` counted from
    ``first_id``, and no catalogue type.

    Ids are fresh at every observation: a camera tells a box from its neighbours in one image,
    not which box of the layout it is, nor that it is the box it saw at the previous step (the
    case's ids are layout positions and would say both).
    """
    items = []
    for i, (item, size) in enumerate(zip(shown, perception.sizes_mm)):
        size_mm = (int(size[0]), int(size[1]), int(size[2]))
        items.append(
            replace(
                item,
                internal_id=f"seen-{first_id + i:05d}",  # zero-padded: sorts as counted
                type_id=0,
                size_mm=size_mm,
                size_cells=size_cells(size_mm, case.container, MEASURED_SIDE_SLACK_MM),
            )
        )
    return tuple(items)


def perceived_rotation(perception: Perception, object_id: int, rotation: int) -> int:
    """The box's own rotation that does what the policy chose: perception names each box's
    sides longer first and says where that swapped the box's own (``axis_swapped``)."""
    if not perception.axis_swapped:
        return rotation
    return rotation ^ int(perception.axis_swapped[object_id])


def grasp_error(perception: Perception, position: int) -> tuple[float, float, float]:
    """The error (dx mm, dy mm, dyaw deg) of the estimated pose of the listed box at
    ``position``; zeros where none is reported."""
    errors = perception.grasp_errors
    if position >= len(errors):
        return NO_GRASP_ERROR
    dx, dy, dyaw = errors[position]
    return (dx, dy, dyaw)


def predicted_after(
    perception: Perception, item: ShownItem, rotation: int, x: int, y: int
) -> np.ndarray:
    """Eq. 2 prediction of the intended placement on the perceived heightmap it was chosen on,
    with the perceived size the policy was shown (``rotation`` as the policy chose it)."""
    l, w, _ = item.size_cells
    footprint = (w, l) if rotation == 1 else (l, w)
    return predict_heightmap(perception.heightmap, x, y, footprint, item.size_mm[2])
