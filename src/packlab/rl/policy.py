"""Policies ``irbpp`` and ``tapnet``: a trained RL agent as a bench policy.

``packlab bench --policies irbpp,tapnet`` plays the agents shipped in the package
(``packlab/data/models/<name>``); ``--policy-arg irbpp:model=RUN/best`` plays another. Each
decision encodes the observation exactly as the training env did
(:func:`packlab.rl.features.encode`), asks the network for its row logits and takes the greedy
row (:func:`packlab.rl.decision.decide`); when no shown box fits anywhere, the box is set aside
as the heuristics do. Option ``overflow`` (default ``score``): where no shown box fits under the
rim, the shared overflow rule decides instead of the network (:mod:`packlab.policies.overflow`).

Option ``runtime``: ``onnx`` (default) runs the directory's ONNX export on ONNX Runtime
(:mod:`packlab.rl.onnx_agent`) and imports neither torch nor stable-baselines3, so the core
install plays it; ``torch`` loads ``model.zip`` with sb3-contrib (rl extra). The two differ only
in who computes the logits. The model is loaded on the first ``reset``, so listing or skipping
these policies needs nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from packlab.core.choices import RUNTIMES, OverflowRule, require_choice
from packlab.core.errors import ConfigError
from packlab.core.feasibility import CandidateSet, observation_candidates
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Observation
from packlab.policies.model_cache import load_once
from packlab.policies.overflow import overflow_decision
from packlab.rl.card import CARD_FILE, AgentCard, read_card
from packlab.rl.decision import RowLogits, decide, ranked_rows
from packlab.rl.extra import RLExtraMissing, import_rl
from packlab.rl.features import FeatureSpec, encode
from packlab.rl.onnx_agent import load_onnx_agent

#: Where the package ships its trained agents, one directory per policy name.
SHIPPED_MODELS = Path(__file__).resolve().parents[1] / "data" / "models"
AGENT_MODULE = "packlab.rl.agent"
OPTIONS = ("model", "threads", "runtime", "overflow")


@dataclass(frozen=True, slots=True)
class _Playing:
    """A loaded agent: what it encodes and who computes its logits."""

    spec: FeatureSpec
    row_logits: RowLogits


class RLAgentPolicy:
    """A trained agent over its action space (module docstring)."""

    def __init__(
        self,
        name: str,
        model: str | None = None,
        threads: int = 1,
        runtime: str = "onnx",
        overflow: OverflowRule = "score",
    ) -> None:
        """``overflow``: where no shown box fits under the rim (or the episode's last box would
        raise the top), ``score`` (the default) lets
        :mod:`packlab.policies.overflow` decide, outside the network, as for the planner that
        taught it; ``place``: the network picks among the boxes sticking out least."""
        require_choice(overflow, OverflowRule, f"policy-arg {name}:overflow")
        self.overflow = overflow
        self.name = name
        self.model_dir = Path(model) if model else SHIPPED_MODELS / name
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ConfigError(f"policy-arg {name}:threads = {threads!r}: must be an int >= 1")
        if runtime not in RUNTIMES:
            raise ConfigError(
                f"policy-arg {name}:runtime = {runtime!r}: must be one of {', '.join(RUNTIMES)} "
                "(onnx: ONNX Runtime, core install; torch: the rl extra)"
            )
        self.threads = threads
        self.runtime = runtime
        self._playing: _Playing | None = None

    def _card(self) -> AgentCard:
        if not self.shipped_present():
            raise ConfigError(
                f"policy {self.name!r}: no agent is shipped in this install ({self.model_dir}); "
                f"train one (docs/rl.md): packlab train rl --agent {self.name} --out RUN, then "
                f"--policy-arg {self.name}:model=RUN/best"
            )
        card = read_card(self.model_dir)
        if card.agent != self.name:
            raise ConfigError(
                f"policy {self.name!r}: model = {str(self.model_dir)!r} is a "
                f"{card.agent!r} agent ({CARD_FILE})"
            )
        return card

    def __getstate__(self) -> dict[str, Any]:
        # Configuration only: a clone loads (or reuses) the agent in its own process.
        return {**self.__dict__, "_playing": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    def _load(self) -> _Playing:
        # One ONNX session (or torch model) per process serves every episode's fresh policy.
        settings = (self.name, self.runtime, self.threads)
        return load_once(self.model_dir, settings, self._load_now)

    def _load_now(self) -> _Playing:
        card = self._card()
        if self.runtime == "onnx":
            return _Playing(card.spec, load_onnx_agent(self.model_dir, self.threads).row_logits)
        try:
            agent = import_rl(AGENT_MODULE)
        except RLExtraMissing as e:
            raise ConfigError(f"policy {self.name!r} (runtime = torch): {e}") from None
        agent.set_threads(self.threads)
        model = agent.load_agent(self.model_dir).model
        return _Playing(card.spec, lambda arrays: agent.row_logits(model, arrays))

    def shipped_present(self) -> bool:
        """False only when the shipped agent is asked for and this install has none."""
        return (
            self.model_dir != SHIPPED_MODELS / self.name or (self.model_dir / CARD_FILE).is_file()
        )

    def _loaded(self) -> _Playing:
        """The agent, loaded on first use (once per process, :func:`load_once`)."""
        if self._playing is None:
            self._playing = self._load()
        return self._playing

    def reset(self, start: EpisodeStart, seed: int) -> None:
        """Load the agent once; it keeps no state between steps."""
        self._loaded()

    def act(self, observation: Observation) -> Action:
        playing = self._loaded()
        cands = observation_candidates(observation)
        overflowed = overflow_decision(observation, cands, self.overflow)
        if overflowed is not None:
            return overflowed
        encoded = encode(observation, playing.spec, cands)
        return decide(encoded, playing.row_logits)

    def ranked_placements(self, observation: Observation, cands: CandidateSet) -> list[int]:
        """The agent's listed placements as flat indices into ``cands`` (the observation's
        candidate set), the one it would take first: what a planner rolls out when an agent
        proposes (:mod:`packlab.policies.plan.guide`). The overflow rule is not applied."""
        playing = self._loaded()
        encoded = encode(observation, playing.spec, cands)
        return [encoded.rows[r] for r in ranked_rows(encoded, playing.row_logits)]


def _make(name: str, options: dict[str, Any]) -> RLAgentPolicy:
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise ConfigError(
            f"policy-arg {name}:{unknown[0]}: unknown option; known: {', '.join(OPTIONS)}"
        )
    threads = options.get("threads", 1)
    runtime = options.get("runtime", "onnx")
    threads = int(threads) if threads else 1
    overflow = options.get("overflow", "score")
    return RLAgentPolicy(name, options.get("model"), threads, runtime, overflow)


def make_irbpp(**options: Any) -> RLAgentPolicy:
    return _make("irbpp", options)


def make_tapnet(**options: Any) -> RLAgentPolicy:
    return _make("tapnet", options)
