"""The agents' network (rl extra): a small CNN over the heightmap plus a shared encoder and
scorer over the item rows, as a Stable-Baselines3 feature extractor and MaskablePPO policy.

Shapes (B = batch, N = item rows, W = ``width``):

- :class:`PackFeatures` maps the observation to one flat vector: the state embedding (W) from
  the CNN over the (1, 32, 32) heightmap and the globals, each item row encoded by one shared
  MLP (N * W), and the item mask (N).
- :class:`ItemPointerPolicy` scores every item with one shared MLP over [item; state]
  (a pointer, as IR-BPP scores its leaf nodes and TAP-Net its boxes), so an item's logit does
  not depend on where it is listed; the value
  is an MLP over [state; masked mean of the items]. SB3's MLP extractor is left empty (identity)
  so both heads read the flat vector.
"""

from __future__ import annotations

import gymnasium as gym
import torch
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from stable_baselines3.common.policies import BaseModel
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

#: Hidden width of every layer unless configured.
DEFAULT_WIDTH = 64


def _split(latent: torch.Tensor, width: int, n_items: int):
    """(state (B, W), items (B, N, W), mask (B, N)) from a :class:`PackFeatures` vector."""
    state = latent[:, :width]
    items = latent[:, width : width + n_items * width].reshape(-1, n_items, width)
    mask = latent[:, width + n_items * width :]
    return state, items, mask


def _shape(space: gym.spaces.Dict, key: str) -> tuple[int, ...]:
    """The shape of one Box of the observation dict (gymnasium types it Optional)."""
    shape = space[key].shape
    if shape is None:
        raise ValueError(f"observation space {key!r} has no shape")
    return shape


class PackFeatures(BaseFeaturesExtractor):
    """Observation dict -> [state (W) | items (N * W) | mask (N)] (module docstring)."""

    def __init__(self, observation_space: gym.spaces.Dict, width: int = DEFAULT_WIDTH) -> None:
        n_items, n_features = _shape(observation_space, "items")
        n_globals = _shape(observation_space, "globals")[0]
        super().__init__(observation_space, width + n_items * width + n_items)
        self.width, self.n_items = width, n_items
        self.cnn = nn.Sequential(  # 32 -> 16 -> 8 -> 4
            nn.Conv2d(1, 16, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(16, 32, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(32, 32, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            cnn_out = self.cnn(torch.zeros(1, *_shape(observation_space, "heightmap"))).shape[1]
        self.state = nn.Sequential(nn.Linear(cnn_out + n_globals, width), nn.ReLU())
        self.items = nn.Sequential(
            nn.Linear(n_features, width), nn.ReLU(), nn.Linear(width, width), nn.ReLU()
        )

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        grid = self.cnn(observations["heightmap"])
        state = self.state(torch.cat([grid, observations["globals"]], dim=1))
        rows = observations["items"]
        items = self.items(rows)
        return torch.cat([state, items.flatten(1), rows[..., 0]], dim=1)


def masked_mean(items: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B, W): the mean of the real rows' encodings (``mask`` (B, R), 1 for a real row)."""
    weights = mask.unsqueeze(-1)
    return (items * weights).sum(1) / weights.sum(1).clamp(min=1.0)


class ItemScores(nn.Module):
    """Action head: one logit per item from a shared MLP over [item; state]."""

    def __init__(self, width: int, n_items: int) -> None:
        super().__init__()
        self.width, self.n_items = width, n_items
        self.mlp = nn.Sequential(nn.Linear(2 * width, width), nn.Tanh(), nn.Linear(width, 1))
        nn.init.orthogonal_(self.mlp[-1].weight, gain=0.01)  # near-uniform first policy
        nn.init.zeros_(self.mlp[-1].bias)

    def score(self, state: torch.Tensor, items: torch.Tensor) -> torch.Tensor:
        """(B, R) logits of any number R of encoded rows (imitation adds rows beyond N)."""
        context = state.unsqueeze(1).expand(-1, items.shape[1], -1)
        return self.mlp(torch.cat([items, context], dim=-1)).squeeze(-1)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        state, items, _ = _split(latent, self.width, self.n_items)
        return self.score(state, items)


class StateValue(nn.Module):
    """Value head: an MLP over [state; masked mean of the items]."""

    def __init__(self, width: int, n_items: int) -> None:
        super().__init__()
        self.width, self.n_items = width, n_items
        self.mlp = nn.Sequential(nn.Linear(2 * width, width), nn.Tanh(), nn.Linear(width, 1))

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        state, items, mask = _split(latent, self.width, self.n_items)
        return self.mlp(torch.cat([state, masked_mean(items, mask)], dim=-1))


class ItemPointerPolicy(MaskableActorCriticPolicy):
    """MaskablePPO's actor-critic with :class:`PackFeatures` and the two item heads."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("features_extractor_class", PackFeatures)
        kwargs["net_arch"] = {"pi": [], "vf": []}  # identity: the heads read the features
        super().__init__(*args, **kwargs)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        fe = self.features_extractor
        self.action_net = ItemScores(fe.width, fe.n_items)
        self.value_net = StateValue(fe.width, fe.n_items)
        self.optimizer = self.optimizer_class(
            self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs
        )


class ActorLogits(nn.Module):
    """A MaskablePPO policy's greedy path as a plain module: (heightmap (B, 1, G, G), globals
    (B, N_GLOBALS), items (B, N, F)) -> raw row logits (B, N), masking left to
    :func:`packlab.rl.decision.pick_row`. It calls the policy's own steps (SB3's observation
    preprocessing, the features extractor, the actor's MLP extractor and the action head) in
    MaskablePPO's order, so the torch runtime and the ONNX export compute one function."""

    def __init__(self, policy: MaskableActorCriticPolicy) -> None:
        super().__init__()
        self.policy = policy
        self.train(False)  # greedy play: evaluation mode, as MaskablePPO.predict sets it

    def forward(
        self, heightmap: torch.Tensor, globals_: torch.Tensor, items: torch.Tensor
    ) -> torch.Tensor:
        observation = {"heightmap": heightmap, "globals": globals_, "items": items}
        # BaseModel's, as MaskableActorCriticPolicy.get_distribution calls it: the actor's
        # extractor whether or not the critic shares it.
        features = BaseModel.extract_features(
            self.policy, observation, self.policy.pi_features_extractor
        )
        return self.policy.action_net(self.policy.mlp_extractor.forward_actor(features))
