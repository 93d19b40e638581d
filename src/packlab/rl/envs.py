"""Gymnasium envs with action spaces a small network can learn (``packlab/Pack-v0``'s flat
(object, rotation, x, y) space has up to 5616 actions; these list K = 16 placements, or one row
per buffer slot).

- ``packlab/PackCandidates-v0`` (:class:`CandidatePlacementEnv`): choose one of the K
  placements the shared proposer lists (IR-BPP-style).
- ``packlab/PackObjects-v0`` (:class:`ObjectChoiceEnv`): choose which shown object to pack, one
  row per buffer slot; a rule places it, the proposer's pick for that box by default
  (``placement``; TAP-Net-style).

Observation: :mod:`packlab.rl.features` (``heightmap`` (1, 32, 32), ``globals`` (8,), ``items``
(N, N_ITEM_FEATURES), float32). Action: ``Discrete(N)``, the item row. ``action_masks()`` (read by
sb3-contrib's ``MaskablePPO``) marks the real rows; every real row is an executable placement.
A step whose state lists nothing (no shown box fits the floor) is taken by the env itself:
the box is set aside (recorded invalid, as the heuristics do) and the next state is shown, so an
agent is only asked when it has a choice. Choosing a masked row does the same (it can only
happen when the mask is ignored).

Reward: :class:`packlab.rl.rewards.StepReward` (default ``overall``: the return is the final
Overall). ``info`` at the end holds ``metrics`` (``EpisodeMetrics.to_dict``), as Pack-v0's.

Modes (as ``packlab bench``'s): ``observation="perceived"`` encodes what the simulated depth
cameras recover under the ``noise`` preset (sizes snapped to the container's grids, or not with
``size_prior="none"``), ``execution="noisy"`` (mujoco) executes each drop with the preset's robot
noise; the reward is judged on the true state either way.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any, cast

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from packlab.cases import load_cases
from packlab.core.choices import (
    DEFAULT_SIDES,
    DEFAULT_SIZE_PRIOR,
    DEFAULT_TAPNET_PLACEMENT,
    ExecutionMode,
    NoisePreset,
    ObservationMode,
    RLAgent,
    RLReward,
    SideNames,
    SizePrior,
    TapnetPlacement,
)
from packlab.core.types import Action, Case
from packlab.policies.candidates import STUDENT_K
from packlab.rl.decision import SET_ASIDE  # the envs set a box aside as the agents do
from packlab.rl.features import (
    FEATURE_MAX,
    GRID,
    N_GLOBALS,
    N_ITEM_FEATURES,
    Encoded,
    FeatureSpec,
    encode,
)
from packlab.rl.rewards import StepReward
from packlab.sim.env import demo_cases_path
from packlab.sim.episode import Episode
from packlab.sim.modes import DEFAULT_NOISE, episode_modes

CANDIDATES_ENV_ID = "packlab/PackCandidates-v0"
OBJECTS_ENV_ID = "packlab/PackObjects-v0"


def observation_space(spec: FeatureSpec) -> spaces.Dict:
    """The Dict space of :func:`packlab.rl.features.encode`'s arrays."""
    return spaces.Dict(
        {
            "heightmap": spaces.Box(0.0, FEATURE_MAX, (1, GRID, GRID), np.float32),
            "globals": spaces.Box(0.0, FEATURE_MAX, (N_GLOBALS,), np.float32),
            "items": spaces.Box(0.0, FEATURE_MAX, (spec.n_items, N_ITEM_FEATURES), np.float32),
        }
    )


class ListedActionEnv(gym.Env):
    """Closed-loop packing where the action picks one of a few listed items (module docstring)."""

    metadata = {"render_modes": []}  # noqa: RUF012 (gymnasium reads a class attribute)

    def __init__(
        self,
        agent: RLAgent,
        cases: str | os.PathLike[str] | Sequence[Case] | None = None,
        backend: str = "geometric",
        reward: RLReward = "overall",
        k: int = STUDENT_K,
        physics: Any = None,
        observation: ObservationMode = "exact",
        execution: ExecutionMode = "exact",
        noise: NoisePreset = DEFAULT_NOISE,
        sides: SideNames = DEFAULT_SIDES,
        placement: TapnetPlacement = DEFAULT_TAPNET_PLACEMENT,
        size_prior: SizePrior = DEFAULT_SIZE_PRIOR,
    ) -> None:
        # The bench's modes (packlab.sim.modes): the agent sees the perceived state; the reward
        # is always judged on the true one. Exact observation names sides as the bench does.
        modes = episode_modes(observation, execution, noise, sides=sides, size_prior=size_prior)
        if cases is None:
            cases = demo_cases_path()
        self.cases = load_cases(cases) if isinstance(cases, (str, os.PathLike)) else list(cases)
        if not self.cases:
            raise ValueError("the env needs at least one case")
        self.spec_features = FeatureSpec.default(agent, k, placement)
        self.observation_space = observation_space(self.spec_features)
        # The terminal observation: zeros of each space's shape (never acted on). Every Box
        # here has a shape; gymnasium types it Optional.
        self._terminal = {
            k: np.zeros(cast(tuple[int, ...], box.shape), np.float32)
            for k, box in self.observation_space.items()
        }
        self.action_space = spaces.Discrete(self.spec_features.n_items)
        self.backend_name = backend
        self._episode = Episode(
            backend,
            physics,
            perceiver=modes.perceiver,
            execution=modes.execution,
            sides=modes.sides,
        )
        self._reward = StepReward(reward)
        self._encoded: Encoded | None = None

    # -- helpers ---------------------------------------------------------------------------
    def _apply(self, action: Action) -> tuple[float, dict[str, Any]]:
        """One episode step; its reward and info."""
        result = self._episode.step(action)
        done = self._episode.done
        reward = self._reward.update(result.positions_mm, self._episode.heightmap, done)
        info: dict[str, Any] = {"valid": result.valid, "reason": result.reason}
        if done:
            info["metrics"] = self._episode.metrics().to_dict()
        return reward, info

    def _advance(self) -> tuple[float, dict[str, Any]]:
        """Encode the state; while nothing is listed, set the box aside (reward summed)."""
        total, info = 0.0, dict[str, Any]()
        while not self._episode.done:
            self._encoded = encode(self._episode.observe(), self.spec_features)
            if self._encoded.actions:
                break
            reward, info = self._apply(SET_ASIDE)
            total += reward
        if self._episode.done:
            self._encoded = None
        return total, info

    def _arrays(self) -> dict[str, np.ndarray]:
        if self._encoded is None:  # terminal: a zero observation, never acted on
            return {k: np.zeros_like(a) for k, a in self._terminal.items()}
        return self._encoded.arrays

    # -- gymnasium API ---------------------------------------------------------------------
    def action_masks(self) -> np.ndarray:
        """(N,) bool: the real item rows (all False once the episode is over)."""
        if self._encoded is None:
            return np.zeros(self.spec_features.n_items, dtype=bool)
        return self._encoded.mask

    def listed_actions(self) -> tuple[Action, ...]:
        """The packing action of each real item row."""
        return () if self._encoded is None else self._encoded.actions

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = options or {}
        index = options.get("case_index")
        if index is None:
            index = int(self.np_random.integers(len(self.cases)))
        case = self.cases[int(index)]
        run_seed = int(options.get("run_seed", self.np_random.integers(2**31 - 1)))
        self._episode.reset(case, run_seed)
        self._reward.reset(case)
        _, info = self._advance()  # a first box that fits nowhere is set aside at once
        info.update({"case_id": case.episode_id, "run_seed": run_seed, "level": case.difficulty})
        # The skipped steps' reward is 0 here (nothing packed yet can change), so none is lost.
        return self._arrays(), info

    def step(self, action):
        if self._episode.case is None:
            raise RuntimeError("step() before reset()")
        row = int(action)
        listed = self.listed_actions()
        reward, info = self._apply(listed[row] if 0 <= row < len(listed) else SET_ASIDE)
        if not self._episode.done:
            more, more_info = self._advance()
            reward += more
            info = {**info, **more_info}
        return self._arrays(), float(reward), self._episode.done, False, info


class CandidatePlacementEnv(ListedActionEnv):
    """IR-BPP-style: the action picks one of the proposer's K listed placements."""

    def __init__(
        self, cases=None, backend="geometric", reward="overall", k=STUDENT_K, physics=None, **modes
    ):
        super().__init__("irbpp", cases, backend, reward, k, physics, **modes)


class ObjectChoiceEnv(ListedActionEnv):
    """TAP-Net-style: the action picks a shown object; a rule (``placement``) places it."""

    def __init__(self, cases=None, backend="geometric", reward="overall", physics=None, **modes):
        super().__init__("tapnet", cases, backend, reward, physics=physics, **modes)


def register_envs() -> None:
    """Register both ids with Gymnasium (idempotent)."""
    if CANDIDATES_ENV_ID not in gym.registry:
        gym.register(id=CANDIDATES_ENV_ID, entry_point=f"{__name__}:CandidatePlacementEnv")
    if OBJECTS_ENV_ID not in gym.registry:
        gym.register(id=OBJECTS_ENV_ID, entry_point=f"{__name__}:ObjectChoiceEnv")


register_envs()
