"""A trained agent on disk and its decisions (rl extra).

A model directory holds ``model.zip`` (sb3-contrib's MaskablePPO save: network weights and
optimiser state) and ``card.json`` (:class:`AgentCard`: the action space, how and on what it was
trained, its held-out scores). :func:`load_agent` reads both; :func:`choose_row` is the one
decision rule the trainer's evaluation, the bench policies and the tests share.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from sb3_contrib import MaskablePPO

from packlab.core.errors import ConfigError
from packlab.core.fileio import write_atomically
from packlab.core.types import Action, Observation
from packlab.rl.envs import SET_ASIDE
from packlab.rl.features import FEATURES_VERSION, Encoded, FeatureSpec, encode

MODEL_FILE = "model.zip"
CARD_FILE = "card.json"
CARD_FORMAT = "packlab-rl-card-1"


@dataclass(frozen=True, slots=True)
class AgentCard:
    """What a model directory holds besides its weights."""

    agent: str
    n_items: int
    reward: str
    env_steps: int = 0
    wall_time_s: float = 0.0
    cores: int = 0
    cases: str = ""  # the training cases' source
    cases_sha256: str = ""
    held_out: dict[str, float] = field(default_factory=dict)  # level -> mean Overall, and avg
    format: str = CARD_FORMAT
    #: What its item rows hold (:data:`packlab.rl.features.FEATURES_VERSION`); a card written
    #: before the field existed is version 1.
    features: int = FEATURES_VERSION

    @property
    def spec(self) -> FeatureSpec:
        return FeatureSpec(self.agent, self.n_items)  # type: ignore[arg-type]


@dataclass(frozen=True, slots=True)
class LoadedAgent:
    card: AgentCard
    model: Any  # MaskablePPO


def write_card(directory: Path, card: AgentCard) -> None:
    text = (json.dumps(asdict(card), indent=1, sort_keys=True) + "\n").encode()
    write_atomically(directory / CARD_FILE, lambda f: f.write(text))


def read_card(directory: Path) -> AgentCard:
    path = directory / CARD_FILE
    if not path.is_file():
        raise ConfigError(f"model = {str(directory)!r}: no {CARD_FILE} (not an RL model directory)")
    try:
        raw = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ConfigError(f"{path}: not JSON ({e})") from None
    if raw.get("format") != CARD_FORMAT:
        raise ConfigError(f"{path}: format = {raw.get('format')!r}, expected {CARD_FORMAT!r}")
    known = set(AgentCard.__dataclass_fields__)
    card = AgentCard(**{"features": 1, **{k: v for k, v in raw.items() if k in known}})
    if card.features != FEATURES_VERSION:
        raise ConfigError(
            f"{path}: features = {card.features}: this packlab's agents read item rows of version "
            f"{FEATURES_VERSION} (placement geometry and level fit); retrain the agent "
            "(packlab train rl-imitate, then packlab train rl --init)"
        )
    return card


def load_agent(directory: str | Path) -> LoadedAgent:
    """The card and the MaskablePPO model of a model directory (on the CPU)."""
    directory = Path(directory)
    card = read_card(directory)
    if not (directory / MODEL_FILE).is_file():
        raise ConfigError(f"model = {str(directory)!r}: no {MODEL_FILE}")
    return LoadedAgent(card, MaskablePPO.load(directory / MODEL_FILE, device="cpu"))


def set_threads(threads: int) -> None:
    """Torch threads for inference (1 in bench workers: episodes already run in parallel)."""
    torch.set_num_threads(threads)


def choose_row(model: Any, encoded: Encoded, deterministic: bool = True) -> int:
    """The item row the model picks for one encoded observation (which lists something)."""
    action, _ = model.predict(
        encoded.arrays, action_masks=encoded.mask, deterministic=deterministic
    )
    return int(np.asarray(action).reshape(-1)[0])


def greedy_action(model: Any, spec: FeatureSpec, observation: Observation) -> Action:
    """The packing action the model takes greedily; the box is set aside when nothing fits."""
    encoded = encode(observation, spec)
    return encoded.actions[choose_row(model, encoded)] if encoded.actions else SET_ASIDE
