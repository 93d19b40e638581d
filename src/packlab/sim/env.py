"""Gymnasium adapter over the packing ``Episode``, registered as ``packlab/Pack-v0``.

Spaces are fixed per environment instance: the grid and buffer are padded to the largest case
the environment may draw, so one policy network can train across container sizes.

* Observation (dict):
  - ``heightmap``: (X, Y) int32 mm; cells outside the drawn container read as its rim height.
  - ``buffer``: (k, 3) int32, the shown objects' (l, w, h) in mm in shown order, zero padded.
  - ``buffer_mask``: (k,) int8, 1 where a shown object exists.
  - ``action_mask``: (k * 2 * X * Y,) int8, 1 where the flattened action is executable
    (object exists and the footprint lies on the container floor).
* Action: ``Discrete(k * 2 * X * Y)``, flattened as (object, rotation, x, y) in C order.
* Reward: the change in packed-volume fraction, i.e. (inside volume after - before) / total
  case volume, so an episode's undiscounted return equals its final Success Ratio. A placement
  that knocks earlier boxes out is penalised by exactly the volume it lost.
* ``info``: per step ``valid``/``reason``; at the end also ``metrics`` (``EpisodeMetrics.to_dict``).
* Modes (as ``packlab bench``'s switches, ``packlab.sim.modes``): ``observation="perceived"``
  shows the heightmap and sizes the simulated depth cameras recover under the ``noise``
  preset (``info["replan"]`` per step), the buffer's boxes told apart by ``segmentation``
  (``"depth"``, the default, or the simulator's ``"truth"`` masks), its size estimates snapped
  to the container's grids or not (``size_prior``: ``"grid"``, the default, or ``"none"``);
  boxes the robot cleared off the buffer unidentified are set aside unpacked;
  ``execution="noisy"`` (mujoco backend) executes each drop with the
  preset's robot noise. Both modes default to ``"exact"``. Exact observation names a box's
  sides longer first (``sides``, the bench's default; ``"catalogue"``: the reference paper's
  protocol, l the side the box lies along x in its perfect layout); a rotation refers to the
  sides as shown.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from importlib import resources
from typing import Any, ClassVar, SupportsInt

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from packlab.cases import load_cases
from packlab.core.choices import (
    DEFAULT_SIDES,
    DEFAULT_SIZE_PRIOR,
    ExecutionMode,
    NoisePreset,
    ObservationMode,
    Segmentation,
    SideNames,
    SizePrior,
)
from packlab.core.feasibility import action_mask, observation_candidates
from packlab.core.types import Action, Case
from packlab.metrics import inside_mask, success_ratio
from packlab.sim.episode import Episode
from packlab.sim.modes import DEFAULT_NOISE, DEFAULT_SEGMENTATION, episode_modes
from packlab.sim.raster import heightmap_to_rgb

ENV_ID = "packlab/Pack-v0"


def demo_cases_path() -> str:
    """The small perfect-layout cases bundled with the package (default for the env)."""
    return str(resources.files("packlab") / "data" / "demo_cases.jsonl")


class InsideVolume:
    """Incremental reward bookkeeping: the inside volume, updated only for boxes that moved.

    A step's reward is the change in Success Ratio (``metrics.success_ratio`` of the inside
    volume), the same float ``Episode.metrics()`` would give, without rescoring the episode:
    only boxes whose settled centre changed this step are re-judged (on the geometric backend
    the one just placed; on MuJoCo also any box the placement pushed).
    """

    def reset(self, case: Case) -> None:
        self._container = case.container
        self._volumes = [b.volume_mm3 for b in case.objects]
        self._total = sum(self._volumes)
        #: (n, 3) float mm, settled centres after the last step; NaN rows: not in the container.
        self._positions = np.full((len(case.objects), 3), np.nan)
        self._inside = np.zeros(len(case.objects), dtype=bool)  # (n,) judged on self._positions
        self.volume = 0  # mm^3 of the inside boxes
        self._fraction = 0.0  # Success Ratio after the last step

    def update(self, positions_mm: np.ndarray) -> float:
        """The reward of the step whose settled centres (n, 3) float mm are ``positions_mm``."""
        before = self._positions
        unchanged = (positions_mm == before) | (np.isnan(positions_mm) & np.isnan(before))
        moved = np.flatnonzero(~np.all(unchanged, axis=1))
        now_inside = inside_mask(positions_mm[moved], self._container)
        for i, inside in zip(moved.tolist(), now_inside.tolist()):
            if inside != self._inside[i]:
                self.volume += self._volumes[i] if inside else -self._volumes[i]
                self._inside[i] = inside
        self._positions = positions_mm.copy()
        fraction = success_ratio(self.volume, self._total)
        reward, self._fraction = fraction - self._fraction, fraction
        return reward


class PackEnv(gym.Env):
    """Closed-loop bin packing as a Gymnasium environment (see the module docstring)."""

    # gymnasium declares Env.metadata an instance variable; it is read as a class attribute.
    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 2}  # type: ignore[misc]

    def __init__(
        self,
        cases: str | os.PathLike[str] | Sequence[Case] | None = None,
        backend: str = "geometric",
        physics: Any = None,
        render_mode: str | None = None,
        observation: ObservationMode = "exact",
        execution: ExecutionMode = "exact",
        noise: NoisePreset = DEFAULT_NOISE,
        segmentation: Segmentation = DEFAULT_SEGMENTATION,
        sides: SideNames = DEFAULT_SIDES,
        size_prior: SizePrior = DEFAULT_SIZE_PRIOR,
    ) -> None:
        # checks names first
        modes = episode_modes(
            observation, execution, noise, segmentation, sides, size_prior=size_prior
        )
        if cases is None:
            cases = demo_cases_path()
        self.cases: list[Case] = (
            load_cases(cases) if isinstance(cases, (str, os.PathLike)) else list(cases)
        )
        if not self.cases:
            raise ValueError("PackEnv needs at least one case")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode = {render_mode!r}: only 'rgb_array' is supported")
        self.render_mode = render_mode
        self.backend_name = backend
        self.grid = (
            max(c.container.cells[0] for c in self.cases),
            max(c.container.cells[1] for c in self.cases),
        )
        self.k = max(c.buffer_size for c in self.cases)
        height_bound = max(
            c.container.height_mm + sum(b.size_mm[2] for b in c.objects) for c in self.cases
        )
        size_bound = max(max(b.size_mm) for c in self.cases for b in c.objects)
        if modes.perceiver is not None:  # two boxes taken for one, snapped a grid step long
            size_bound = 2 * size_bound + max(c.container.cell_xy_mm for c in self.cases)
        n_actions = self.k * 2 * self.grid[0] * self.grid[1]
        self.observation_space = spaces.Dict(
            {
                "heightmap": spaces.Box(0, height_bound, shape=self.grid, dtype=np.int32),
                "buffer": spaces.Box(0, size_bound, shape=(self.k, 3), dtype=np.int32),
                "buffer_mask": spaces.Box(0, 1, shape=(self.k,), dtype=np.int8),
                "action_mask": spaces.Box(0, 1, shape=(n_actions,), dtype=np.int8),
            }
        )
        self.action_space = spaces.Discrete(n_actions)
        self._episode = Episode(
            backend,
            physics,
            perceiver=modes.perceiver,
            execution=modes.execution,
            sides=modes.sides,
        )
        self._case: Case | None = None
        self._reward = InsideVolume()

    # -- encoding --------------------------------------------------------------------------
    def decode_action(self, index: int) -> Action:
        obj, rotation, x, y = np.unravel_index(int(index), (self.k, 2, *self.grid))
        return Action(int(obj), int(rotation), int(x), int(y))

    def encode_action(self, action: Action) -> int:
        return int(
            np.ravel_multi_index(
                (action.object_id, action.rotation, action.x, action.y), (self.k, 2, *self.grid)
            )
        )

    def _observation(self, case: Case) -> dict[str, np.ndarray]:
        hm = np.full(self.grid, case.container.height_mm, dtype=np.int32)
        cx, cy = case.container.cells
        hm[:cx, :cy] = self._episode.observed_heightmap  # the perceived one in perceived mode
        buffer = np.zeros((self.k, 3), dtype=np.int32)
        buffer_mask = np.zeros(self.k, dtype=np.int8)
        mask = np.zeros((self.k, 2, *self.grid), dtype=np.int8)
        if not self._episode.done:
            observation = self._episode.observe()
            for item in observation.shown:
                buffer[item.shown_index] = item.size_mm
                buffer_mask[item.shown_index] = 1
            fits = action_mask(observation_candidates(observation))  # (shown, 2, cx, cy)
            mask[: fits.shape[0], :, : fits.shape[2], : fits.shape[3]] = fits
        return {
            "heightmap": hm,
            "buffer": buffer,
            "buffer_mask": buffer_mask,
            "action_mask": mask.reshape(-1),
        }

    # -- gymnasium API ---------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        options = options or {}
        index = options.get("case_index")
        if index is None:
            index = int(self.np_random.integers(len(self.cases)))
        case = self._case = self.cases[int(index)]
        run_seed = int(options.get("run_seed", self.np_random.integers(2**31 - 1)))
        self._episode.reset(case, run_seed)
        self._reward.reset(case)
        return self._observation(case), {"case_id": case.episode_id, "run_seed": run_seed}

    def step(
        self, action: SupportsInt
    ) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if self._case is None:
            raise RuntimeError("PackEnv.step() before reset()")
        result = self._episode.step(self.decode_action(int(action)))
        reward = self._reward.update(result.positions_mm)
        terminated = self._episode.done
        info: dict[str, Any] = {"valid": result.valid, "reason": result.reason}
        if result.replan is not None:  # perceived mode: the scan departed from the plan
            info["replan"] = result.replan
        if terminated:
            info["metrics"] = self._episode.metrics().to_dict()
        return self._observation(self._case), float(reward), terminated, False, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array" or self._case is None:
            return None
        return heightmap_to_rgb(self._episode.heightmap, self._case.container)


def register_envs() -> None:
    """Register ``packlab/Pack-v0`` with Gymnasium (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="packlab.sim.env:PackEnv")


register_envs()
