"""Behaviour cloning of the item-pointer actor from imitation samples (rl extra).

:func:`imitate` builds a MaskablePPO agent exactly as ``packlab train rl`` does
(:func:`packlab.rl.train.make_model`), fits its actor by cross-entropy between the masked row
logits and the samples' targets (soft or one-hot, over a variable number of rows) and, where the
samples carry one, its value head to the episode's final Overall (squared error). It starts from
fresh weights or from a trained agent's (``init``: a DAgger round on the states that agent
reached), then saves a model directory :func:`packlab.rl.agent.load_agent` reads and ``packlab
train rl --init`` starts PPO from, with its ONNX export (the bench plays it without torch).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.vec_env import DummyVecEnv

from packlab.core.errors import ConfigError
from packlab.policies.provenance import card_path, card_source, provenance
from packlab.rl.card import AgentCard
from packlab.rl.config import ImitationConfig, RLTrainConfig
from packlab.rl.envs import ListedActionEnv
from packlab.rl.features import FeatureSpec
from packlab.rl.imitation import Sample
from packlab.rl.train import export_model_dirs, load_init, make_model, save_model_dir

#: Logit given to padded rows (masked out of the softmax).
MASKED = -1e9


@dataclass(slots=True)
class ImitationResult:
    out: Path
    losses: list[float] = field(default_factory=list)  # mean actor loss per epoch
    accuracy: float = 0.0  # share of samples whose argmax row carries the most target
    n_samples: int = 0
    wall_time_s: float = 0.0


def collate(samples: Sequence[Sample]) -> dict[str, torch.Tensor]:
    """Stack samples, padding item rows (and targets) with zeros to the longest."""
    rows = max(len(s.items) for s in samples)
    n_features = samples[0].items.shape[1]
    items = np.zeros((len(samples), rows, n_features), dtype=np.float32)
    target = np.zeros((len(samples), rows), dtype=np.float32)
    for b, s in enumerate(samples):
        items[b, : len(s.items)] = s.items
        target[b, : len(s.target)] = s.target
    return {
        "heightmap": torch.as_tensor(np.stack([s.heightmap for s in samples])),
        "globals": torch.as_tensor(np.stack([s.globals for s in samples])),
        "items": torch.as_tensor(items),
        "target": torch.as_tensor(target),
        "value": torch.as_tensor(np.array([s.value for s in samples], dtype=np.float32)),
    }


def row_logits(policy: Any, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """(B, R) masked logits of any number R of rows, with the policy's own modules (the
    features extractor's CNN, state and item encoders and the action head's shared MLP)."""
    fe = policy.features_extractor
    state = fe.state(torch.cat([fe.cnn(batch["heightmap"]), batch["globals"]], dim=1))
    mask = batch["items"][..., 0]
    logits = policy.action_net.score(state, fe.items(batch["items"]))
    return logits.masked_fill(mask <= 0, MASKED)


def state_value(policy: Any, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """(B,) the value head on the first N rows (what PPO's critic sees)."""
    n = policy.features_extractor.n_items
    obs = {
        "heightmap": batch["heightmap"],
        "globals": batch["globals"],
        "items": batch["items"][:, :n],
    }
    if obs["items"].shape[1] < n:
        pad = n - obs["items"].shape[1]
        obs["items"] = torch.nn.functional.pad(obs["items"], (0, 0, 0, pad))
    return policy.value_net(policy.features_extractor(obs)).squeeze(-1)


def batch_loss(policy: Any, batch: dict[str, torch.Tensor], value_weight: float):
    """(total loss, actor cross-entropy, argmax-hits) of one batch."""
    logits = row_logits(policy, batch)
    ce = -(batch["target"] * torch.log_softmax(logits, dim=-1)).sum(-1).mean()
    hits = (batch["target"].gather(1, logits.argmax(-1, keepdim=True)).squeeze(1)) >= (
        batch["target"].max(-1).values - 1e-6
    )
    loss = ce
    has = ~torch.isnan(batch["value"])
    if value_weight > 0 and bool(has.any()):
        v = state_value(policy, batch)
        loss = loss + value_weight * ((v[has] - batch["value"][has]) ** 2).mean()
    return loss, float(ce.detach()), int(hits.sum())


def fit(policy: Any, samples: Sequence[Sample], cfg: ImitationConfig) -> ImitationResult:
    """Fit ``policy`` in place for ``cfg.epochs`` epochs (Adam, shuffled minibatches)."""
    if not samples:
        raise ConfigError("imitation: no samples with a target")
    rng = np.random.default_rng(cfg.seed)
    optimizer = torch.optim.Adam(policy.parameters(), lr=cfg.lr)
    result = ImitationResult(Path(cfg.out), n_samples=len(samples))
    policy.set_training_mode(True)
    for _ in range(cfg.epochs):
        order = rng.permutation(len(samples))
        total, hits = 0.0, 0
        for start in range(0, len(order), cfg.batch):
            part = [samples[i] for i in order[start : start + cfg.batch]]
            loss, ce, hit = batch_loss(policy, collate(part), cfg.value_weight)
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 0.5)
            optimizer.step()
            total += ce * len(part)
            hits += hit
        result.losses.append(total / len(samples))
        result.accuracy = hits / len(samples)
    policy.set_training_mode(False)
    return result


def new_model(cfg: ImitationConfig, out: Path) -> Any:
    """A fresh MaskablePPO agent as ``packlab train rl`` makes one (spaces from the demo case)."""
    agent: Any = cfg.agent
    rl_cfg = RLTrainConfig(agent=agent, k=cfg.k, width=cfg.width, seed=cfg.seed, envs=1)
    venv = DummyVecEnv([lambda: ListedActionEnv(agent, None, k=cfg.k, placement=cfg.placement)])
    return make_model(rl_cfg, venv, out)


def imitate(
    samples: Sequence[Sample],
    cfg: ImitationConfig,
    source: str = "",
    cases: tuple[str, str] = ("", ""),
) -> ImitationResult:
    """Behaviour-clone an agent on ``samples`` (fresh, or from ``cfg.init``'s weights) and save
    it under ``cfg.out`` (a model dir).
    ``source``: the states file; ``cases``: (source, cases_sha256) of the cases the states were
    checked against, if any."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    model = new_model(cfg, out)
    if cfg.init:
        load_init(model, cfg.init, FeatureSpec.default(cfg.agent, cfg.k, cfg.placement))
    result = fit(model.policy, samples, cfg)
    result.wall_time_s = time.perf_counter() - started
    card = AgentCard(
        agent=cfg.agent,
        n_items=FeatureSpec.default(cfg.agent, cfg.k).n_items,  # type: ignore[arg-type]
        placement=cfg.placement,
        reward="overall",
        wall_time_s=round(result.wall_time_s, 1),
        cores=os.cpu_count() or 0,  # as a PPO run's card: the machine the time was taken on
        cases=card_source(cases[0], out) if cases[0] else "imitation",
        cases_sha256=cases[1],
        # No selection: the model after the last epoch is kept.
        **provenance(out, cfg.seed, init=cfg.init or None, states=[source] if source else []),
    )
    save_model_dir(model, out, card)
    export_model_dirs(out)
    record = {"config": asdict(cfg), "n_samples": result.n_samples}
    record |= {"source": card_path(source, out) if source else ""}
    record |= {"losses": result.losses, "accuracy": result.accuracy}
    (out / "imitation.json").write_text(json.dumps(record, indent=1) + "\n")
    return result
