"""Per-step box poses of an episode, compact: only the boxes placed or moved at each step.

Records keep every box's settled pose after the last step (``final_poses``); a replay of the
episode (the HTML report, the Rerun viewer) also needs the poses in between. Writing every box
at every step would make records O(steps x boxes); a settled pile barely moves, so a step lists
only the boxes whose pose differs from the last pose written for them by more than a
tolerance (about 1.1 entries per step on packlab-bench-v1 with MuJoCo; exactly one, the placed
box, on the geometric backend). Comparing with the last *written* pose, not the previous step's,
keeps slow drift from escaping: every shown pose is within the tolerance of the true one.

An entry is ``(object index, x, y, z, qw, qx, qy, qz)``: the index into the case's objects, the
centre in mm rounded to 0.1 mm and the unit quaternion rounded to 1e-4.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from packlab.core.records import PoseEntry

#: A box is written again once its centre moved more than this (mm) ...
POSE_TOLERANCE_MM = 0.5
#: ... or a quaternion component changed more than this (about 0.1 degree).
POSE_TOLERANCE_QUAT = 1e-3


def pose_entry(index: int, position: Sequence[float], quaternion: Sequence[float]) -> PoseEntry:
    """A logged pose, rounded as records keep it (0.1 mm, 1e-4)."""
    p = [round(float(v), 1) for v in position]
    q = [round(float(v), 4) for v in quaternion]
    return (index, p[0], p[1], p[2], q[0], q[1], q[2], q[3])


def _moved(p: np.ndarray, q: np.ndarray, last_p: np.ndarray, last_q: np.ndarray) -> bool:
    # q and -q are the same rotation: compare with the nearer of the two.
    dq = min(float(np.abs(q - last_q).max()), float(np.abs(q + last_q).max()))
    return float(np.abs(p - last_p).max()) > POSE_TOLERANCE_MM or dq > POSE_TOLERANCE_QUAT


def pose_updates(
    positions: Sequence[np.ndarray], quaternions: Sequence[np.ndarray]
) -> list[list[PoseEntry]]:
    """For each step, the boxes placed or moved by more than the tolerance.

    ``positions[i]`` (n, 3) float mm and ``quaternions[i]`` (n, 4) wxyz are the poses of all n
    boxes after step i, NaN rows for boxes not in the scene (not placed yet, or set aside).
    """
    last: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    out: list[list[PoseEntry]] = []
    for pos, quat in zip(positions, quaternions):
        step: list[PoseEntry] = []
        for i in map(int, np.flatnonzero(~np.isnan(pos).any(axis=1))):
            p, q = pos[i], quat[i]
            if i in last and not _moved(p, q, *last[i]):
                continue
            last[i] = (p, q)
            step.append(pose_entry(i, p, q))
        out.append(step)
    return out


def poses_after(updates: Sequence[Sequence[PoseEntry]], step: int) -> dict[int, PoseEntry]:
    """Every box's latest logged pose after ``step`` (0-based), by object index."""
    state: dict[int, PoseEntry] = {}
    for entries in updates[: step + 1]:
        for e in entries:
            state[int(e[0])] = e
    return state


__all__ = [
    "POSE_TOLERANCE_MM",
    "POSE_TOLERANCE_QUAT",
    "PoseEntry",
    "pose_entry",
    "pose_updates",
    "poses_after",
]
