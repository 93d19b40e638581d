"""An agent's ``card.json`` (torch-free): what a model directory holds besides its weights.

One implementation for everyone who reads or writes the card: the trainer and the imitation fit
(rl extra), the torch loader (:mod:`packlab.rl.agent`) and the ONNX player
(:mod:`packlab.rl.onnx_agent`, core install).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from packlab.core.choices import (
    DEFAULT_TAPNET_PLACEMENT,
    UNRECORDED_TAPNET_PLACEMENT,
    TapnetPlacement,
    choices,
)
from packlab.core.errors import ConfigError
from packlab.core.fileio import write_atomically
from packlab.rl.features import FEATURES_VERSION, FeatureSpec

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
    cases: str = ""  # the training cases' source: suite:/recipe: name or a file name, no path
    cases_sha256: str = ""
    held_out: dict[str, float] = field(default_factory=dict)  # level -> mean Overall, and avg
    format: str = CARD_FORMAT
    #: What its item rows hold (:data:`packlab.rl.features.FEATURES_VERSION`); a card written
    #: before the field existed is version 1.
    features: int = FEATURES_VERSION
    # How the model was made (packlab.policies.provenance). Cards written before these
    # fields read with them empty. Paths are relative to the run directory or names only.
    seed: int | None = None
    commit: str | None = None  # git rev-parse HEAD of the packlab checkout; None outside one
    dirty: bool | None = None  # tracked files differed from that commit
    init: dict[str, str] | None = None  # the checkpoint started from: path (name), sha256
    states: list[dict[str, str | None]] = field(default_factory=list)  # imitation: path, sha256
    #: The cases the kept model was chosen on: sha256 (content, order-free), n, rule.
    selection: dict[str, Any] | None = None
    #: tapnet: the rule that places the chosen object (``core.choices.TapnetPlacement``); a
    #: card written before the field existed used DBLF's.
    placement: str = DEFAULT_TAPNET_PLACEMENT

    @property
    def spec(self) -> FeatureSpec:
        return FeatureSpec(self.agent, self.n_items, self.placement)  # type: ignore[arg-type]


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
    unrecorded = {"features": 1, "placement": UNRECORDED_TAPNET_PLACEMENT}
    card = AgentCard(**{**unrecorded, **{k: v for k, v in raw.items() if k in known}})
    if card.placement not in choices(TapnetPlacement):
        raise ConfigError(
            f"{path}: placement = {card.placement!r}: expected one of "
            f"{', '.join(choices(TapnetPlacement))}"
        )
    if card.features != FEATURES_VERSION:
        raise ConfigError(
            f"{path}: features = {card.features}: this packlab's agents read item rows of version "
            f"{FEATURES_VERSION} (placement geometry and level fit); retrain the agent "
            "(packlab train rl-imitate, then packlab train rl --init)"
        )
    return card
