"""A trained agent proposing first placements to the planner's lookahead (``guide``).

The lookahead rolls out a few first placements (:mod:`.proposer`: SDF-Pack's, a flush ranking's
and the students' proposer's) and commits the cheapest. Its rankings are rules, and on boxes of
independent sizes, where no exact tiling exists and the lookahead decides most steps, a trained
agent's first pick was as good as the whole lookahead (IR-BPP scored above ``plan`` on
random boxes). With ``guide=irbpp`` the agent's ``guide_first`` preferred placements are rolled
out too, and the end-state cost decides between them and the rules' (a rollout over a base
policy's proposals, as policy improvement by rollout does).

The agent reads only the observation (its encoding is the one it was trained on) and runs on
ONNX Runtime, so the core install plays it. It is loaded on the first lookahead decision, once
per process. Off by default: its gain on generated random-box training cases did not carry to
the evaluation set (docs/planner.md, Knobs).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from packlab.core.choices import RLAgent, choices
from packlab.core.errors import ConfigError
from packlab.core.feasibility import CandidateSet
from packlab.core.types import Observation
from packlab.policies.registry import make_policy


@runtime_checkable
class RanksPlacements(Protocol):
    """A policy that orders the placements of a candidate set by its own preference (the RL
    agents: ``packlab.rl.policy.RLAgentPolicy.ranked_placements``). The guide makes it through
    the policy registry, so the planner does not import the layer above it."""

    def ranked_placements(self, observation: Observation, cands: CandidateSet) -> list[int]: ...


#: Agents that can guide: none, or an RL agent kind (the shipped one, or ``guide_model``).
GUIDE_AGENTS: tuple[str, ...] = ("none", *choices(RLAgent))


@dataclass
class AgentGuide:
    """Which agent proposes (``agent``; ``"none"``: no agent), from which model directory
    (``model``; None: the shipped one) and how many of its placements (``first``)."""

    agent: str = "none"
    model: str | None = None
    first: int = 2
    _policy: RanksPlacements | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.agent not in GUIDE_AGENTS:
            raise ConfigError(
                f"plan: guide = {self.agent!r}: must be one of {', '.join(GUIDE_AGENTS)}"
            )
        if isinstance(self.first, bool) or not isinstance(self.first, int) or self.first < 0:
            raise ConfigError(f"plan: guide_first = {self.first!r}: must be a whole number >= 0")
        if self.model is not None and self.agent == "none":
            raise ConfigError(f"plan: guide_model = {self.model!r} needs guide = irbpp or tapnet")

    @property
    def active(self) -> bool:
        return self.agent != "none" and self.first > 0

    def placements(self, observation: Observation, cands: CandidateSet) -> list[int]:
        """The agent's ``first`` preferred placements, flat indices into ``cands`` (empty when
        the guide is off or nothing is listed)."""
        if not self.active:
            return []
        if self._policy is None:
            agent = make_policy(self.agent, **({"model": self.model} if self.model else {}))
            if not isinstance(agent, RanksPlacements):
                raise ConfigError(f"plan: guide = {self.agent!r} cannot rank placements")
            self._policy = agent
        return self._policy.ranked_placements(observation, cands)[: self.first]

    def __getstate__(self) -> dict[str, object]:
        # Configuration only: a worker process loads (or reuses) the agent itself.
        return {**self.__dict__, "_policy": None}

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
