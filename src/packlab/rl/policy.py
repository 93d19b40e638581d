"""Policies ``irbpp`` and ``tapnet``: a trained RL agent as a bench policy (rl extra).

``packlab bench --policies irbpp,tapnet`` plays the agents shipped in the package
(``packlab/data/models/<name>``); ``--policy-arg irbpp:model=RUN/best`` plays another. Each
decision encodes the observation exactly as the training env did
(:func:`packlab.rl.features.encode`) and takes the agent's greedy row; when no shown box fits
anywhere, the box is set aside as the heuristics do. The stable-baselines3 stack is imported
when the model is loaded (on the first ``reset``), so listing or skipping these policies needs
no extra.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from packlab.core.errors import ConfigError
from packlab.core.types import Action, Case, Observation
from packlab.rl.extra import RLExtraMissing, import_rl

#: Where the package ships its trained agents, one directory per policy name.
SHIPPED_MODELS = Path(__file__).resolve().parents[1] / "data" / "models"
AGENT_MODULE = "packlab.rl.agent"
OPTIONS = ("model", "threads")


class RLAgentPolicy:
    """A trained agent over its action space (module docstring)."""

    def __init__(self, name: str, model: str | None = None, threads: int = 1) -> None:
        self.name = name
        self.model_dir = Path(model) if model else SHIPPED_MODELS / name
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ConfigError(f"policy-arg {name}:threads = {threads!r}: must be an int >= 1")
        self.threads = threads
        self._loaded: Any = None

    def _load(self) -> Any:
        try:
            agent = import_rl(AGENT_MODULE)
        except RLExtraMissing as e:
            raise ConfigError(f"policy {self.name!r}: {e}") from None
        agent.set_threads(self.threads)
        if not self.shipped_present():
            raise ConfigError(
                f"policy {self.name!r}: no agent is shipped in this install ({self.model_dir}); "
                f"train one (docs/rl.md): packlab train rl --agent {self.name} --out RUN, then "
                f"--policy-arg {self.name}:model=RUN/best"
            )
        loaded = agent.load_agent(self.model_dir)
        if loaded.card.agent != self.name:
            raise ConfigError(
                f"policy {self.name!r}: model = {str(self.model_dir)!r} is a "
                f"{loaded.card.agent!r} agent (card.json)"
            )
        self._greedy = agent.greedy_action
        return loaded

    def shipped_present(self) -> bool:
        """False only when the shipped agent is asked for and this install has none."""
        return (
            self.model_dir != SHIPPED_MODELS / self.name or (self.model_dir / "card.json").is_file()
        )

    def reset(self, case: Case, seed: int) -> None:
        """Load the agent once; it keeps no state between steps."""
        if self._loaded is None:
            self._loaded = self._load()

    def act(self, observation: Observation) -> Action:
        if self._loaded is None:
            self._loaded = self._load()
        return self._greedy(self._loaded.model, self._loaded.card.spec, observation)


def _make(name: str, options: dict[str, Any]) -> RLAgentPolicy:
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise ConfigError(
            f"policy-arg {name}:{unknown[0]}: unknown option; known: {', '.join(OPTIONS)}"
        )
    threads = options.get("threads", 1)
    return RLAgentPolicy(name, options.get("model"), int(threads) if threads else 1)


def make_irbpp(**options: Any) -> RLAgentPolicy:
    return _make("irbpp", options)


def make_tapnet(**options: Any) -> RLAgentPolicy:
    return _make("tapnet", options)
