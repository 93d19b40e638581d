"""Replay a recorded episode: the same case, run seed and actions give the same episode.

Records keep actions, not heightmaps (heightmaps per step would make records 100x larger). The
episode is deterministic in (case, run seed, actions, backend, physics config), so the step
heightmaps a figure needs are recomputed here by stepping the recorded actions again.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from packlab.core.choices import DEFAULT_SIDES, SideNames
from packlab.core.errors import ConfigError
from packlab.core.packing_protocol import BUFFER, PackingProtocol
from packlab.core.records import EpisodeOk, EpisodeRecord, StepRecord
from packlab.core.types import Action, Case, Unparsable
from packlab.sim.episode import Episode


def action_from_record(step: StepRecord) -> Action | Unparsable:
    """The action of a step record."""
    return step.action.to_action()


@dataclass(frozen=True, slots=True)
class Replay:
    """The heightmap after every step and the replayed final scores."""

    heightmaps: tuple[np.ndarray, ...]  # (x_cells, y_cells) int32 mm after step i
    overall: float
    success_ratio: float
    compactness: float
    matches_record: bool  # replayed scores and processed objects equal the recorded ones


def replay_record(
    case: Case,
    record: EpisodeRecord,
    physics: Any = None,
    sides: SideNames = DEFAULT_SIDES,
    protocol: PackingProtocol = BUFFER,
) -> Replay:
    """Step a record's actions through a fresh episode on the record's backend, with the side
    names the run showed (``packlab.bench.config.run_sides``): a recorded rotation refers to
    them; and under the run's protocol (``core.packing_protocol.saved_protocol``): a recorded
    object index refers to the buffer that protocol showed."""
    if not isinstance(record, EpisodeOk):
        raise ConfigError(
            f"record {record.case_id}/{record.policy}/seed {record.seed}: "
            f"status {record.status!r} has no actions to replay"
        )
    if record.case_id != case.episode_id:
        raise ConfigError(
            f"record case_id = {record.case_id!r} does not match case {case.episode_id!r}"
        )
    episode = Episode(record.backend, physics, sides=sides, protocol=protocol)
    episode.reset(case, record.seed)
    heightmaps, same_objects = [], True
    for step in record.steps:
        result = episode.step(action_from_record(step))
        heightmaps.append(episode.heightmap.copy())
        same_objects &= result.internal_id == step.internal_id and result.valid == step.valid
    m = episode.metrics()
    rec = record.metrics
    same_scores = all(
        abs(getattr(m, k) - float(getattr(rec, k))) <= 1e-6
        for k in ("overall", "success_ratio", "compactness")
    )
    return Replay(
        tuple(heightmaps),
        m.overall,
        m.success_ratio,
        m.compactness,
        bool(same_objects and same_scores),
    )


__all__ = ["Replay", "action_from_record", "replay_record"]
