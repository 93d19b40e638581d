"""Imitation targets: a teacher's decision as the agent's arrays and a target over its rows
(pure, torch-free; the fit is :mod:`packlab.rl.imitation_fit`).

Works from any (observation, teacher action, optional soft preference over actions) pairs, so it
depends on no labels file format (the CLI and scripts convert the candidate-mode states).

- ``irbpp``: the rows are the proposer's K listed placements (:func:`encode`); the target is
  the row whose placement equals the teacher's. A teacher placement the proposer did not list is
  added as an extra row (imitation only: K + 1 or more rows). The pointer network scores every
  row with shared weights, so the row count may vary (:func:`packlab.rl.imitation_fit.row_logits`).
- ``tapnet``: one row per shown object placed by DBLF's rule; the target is the row of the
  object the teacher packs, spread uniformly over every shown object of identical size (boxes
  of one size are interchangeable: the teacher's choice among them is arbitrary).

A soft preference is a list of (action, weight); each weight goes to its action's row(s) as above
and the target is normalised to sum to 1. Weights of actions with no row are dropped.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from packlab.core.feasibility import CandidateSet, observation_candidates
from packlab.core.types import Action, Observation
from packlab.policies.candidates import placement_index
from packlab.policies.features import walled
from packlab.policies.heuristics.select import object_rank
from packlab.rl.features import FeatureSpec, encode, item_row


@dataclass(frozen=True, slots=True)
class Demo:
    """One teacher decision: what it saw, what it did, and optionally how much it preferred
    other actions (``soft``) and the Overall its episode ended with (``value``)."""

    observation: Observation
    action: Action
    soft: tuple[tuple[Action, float], ...] = ()
    value: float | None = None


@dataclass(frozen=True, slots=True)
class Sample:
    """Arrays as the agent sees them, ``items`` with R >= 0 rows (possibly more than the spec's
    N: added teacher rows), the target over those R rows (sums to 1), and the value target."""

    heightmap: np.ndarray  # (1, G, G)
    globals: np.ndarray  # (N_GLOBALS,)
    items: np.ndarray  # (R, F)
    target: np.ndarray  # (R,) float32
    value: float  # nan: none given
    added: bool  # a row was added for the teacher (irbpp, proposer missed it)


def _key(a: Action) -> tuple[int, int, int, int]:
    return (int(a.object_id), int(a.rotation), int(a.x), int(a.y))


def size_key(observation: Observation, object_index: int) -> tuple[int, ...]:
    """A shown box's size as an orientation-free key (sorted sides, mm)."""
    return tuple(sorted(int(v) for v in observation.shown[object_index].size_mm))


def _extra_row(cands: CandidateSet, observation: Observation, action: Action) -> np.ndarray | None:
    """The item row of a placement the rows do not list (None: not a placement of the set)."""
    i = placement_index(cands, action.object_id, action.rotation, action.x, action.y)
    if i is None:
        return None
    ranks = object_rank(cands.shown_sizes_mm, cands.shown_id_order)
    walls = walled(cands.heightmap, cands.container_height_mm)
    return item_row(observation, cands, walls, i, int(ranks[int(cands.obj[i])]))


def _tapnet_weights(obs: Observation, actions, prefs) -> np.ndarray:
    """Each preferred object's weight spread over the rows of objects of identical size."""
    weights = np.zeros(len(actions), dtype=np.float64)
    keys = [size_key(obs, a.object_id) for a in actions]
    for action, w in prefs:
        if not 0 <= action.object_id < len(obs.shown):
            continue
        same = [r for r, k in enumerate(keys) if k == size_key(obs, action.object_id)]
        for r in same:
            weights[r] += w / len(same)
    return weights


def imitation_sample(demo: Demo, spec: FeatureSpec) -> Sample | None:
    """The agent's arrays and the target over its rows for one demo (module docstring); None
    when no row carries any of the teacher's preference (e.g. nothing is listed)."""
    obs = demo.observation
    cands = observation_candidates(obs)
    encoded = encode(obs, spec, cands)
    items = encoded.arrays["items"][: len(encoded.actions)]
    actions = list(encoded.actions)
    prefs = list(demo.soft) or [(demo.action, 1.0)]
    added = False
    if spec.agent == "tapnet":
        weights = _tapnet_weights(obs, actions, prefs)
    else:
        rows = {_key(a): r for r, a in enumerate(actions)}
        extra: list[np.ndarray] = []
        for action, w in prefs:
            if _key(action) not in rows and w > 0:
                row = _extra_row(cands, obs, action)
                if row is not None:
                    rows[_key(action)] = len(actions) + len(extra)
                    extra.append(row)
                    added = added or _key(action) == _key(demo.action)
        if extra:
            items = np.concatenate([items, np.stack(extra)])
        weights = np.zeros(len(items), dtype=np.float64)
        for action, w in prefs:
            if _key(action) in rows:
                weights[rows[_key(action)]] += w
    if weights.sum() <= 0:
        return None
    value = float("nan") if demo.value is None else float(demo.value)
    return Sample(
        encoded.arrays["heightmap"],
        encoded.arrays["globals"],
        items.astype(np.float32),
        (weights / weights.sum()).astype(np.float32),
        value,
        added,
    )


def imitation_samples(demos: Sequence[Demo], spec: FeatureSpec) -> list[Sample]:
    """:func:`imitation_sample` of every demo that has a target."""
    out = [imitation_sample(d, spec) for d in demos]
    return [s for s in out if s is not None]
