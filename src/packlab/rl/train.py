"""``packlab train rl``: MaskablePPO (sb3-contrib) on an action-space env (rl extra).

A run directory holds ``config.json`` (the resolved :class:`RLTrainConfig` and the cases'
source), ``checkpoint.zip`` + ``state.json`` (written together at every evaluation: rerunning
the same command resumes from them after a crash or a stop), ``log.csv`` (one row per
evaluation), ``best/`` (the checkpoint with the best held-out score so far) and ``final/`` (the
last), each a model directory :func:`packlab.rl.agent.load_agent` reads and, once the run
ends, exported to ONNX (:mod:`packlab.rl.onnx_export`: the bench's default runtime plays it
without torch), and ``tb/`` when TensorBoard is installed. Training runs on the geometric
backend (exact Eq. 2, fast); the bench scores the agents under MuJoCo.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from sb3_contrib import MaskablePPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

from packlab.core.errors import ConfigError
from packlab.core.fileio import write_atomically
from packlab.core.types import Case
from packlab.policies.provenance import card_source, provenance, selection_record
from packlab.rl.card import MODEL_FILE, AgentCard, read_card, write_card
from packlab.rl.config import RLTrainConfig
from packlab.rl.envs import ListedActionEnv
from packlab.rl.evaluate import evaluate
from packlab.rl.features import FeatureSpec
from packlab.rl.networks import ItemPointerPolicy
from packlab.rl.onnx_export import export_onnx
from packlab.rl.split import hold_out

LOG_FIELDS = ("env_steps", "wall_s", "steps_per_s", "train_return", "easy", "medium", "hard", "avg")
#: Config fields a resumed run must share with the run it continues (the rest may change,
#: e.g. a larger ``steps`` to train on).
FIXED_ON_RESUME = ("agent", "reward", "k", "width", "seed")
#: States on which a run's ONNX export must pick torch's rows (as ``packlab export onnx``).
EXPORT_CHECK_STATES = 64


@dataclass(frozen=True, slots=True)
class RLRunResult:
    out: Path
    env_steps: int
    wall_time_s: float
    best: dict[str, float]  # held-out scores of best/
    final: dict[str, float]


def _make_env(cfg: RLTrainConfig, cases: Sequence[Case]) -> ListedActionEnv:
    return ListedActionEnv(
        cfg.agent, list(cases), "geometric", cfg.reward, cfg.k, placement=cfg.placement
    )


def make_vec_env(cfg: RLTrainConfig, cases: Sequence[Case]) -> VecMonitor:
    """``cfg.envs`` copies of the env (processes or in-process), seeded, with episode stats."""
    fns: list[Callable[[], gym.Env]] = [partial(_make_env, cfg, cases) for _ in range(cfg.envs)]
    venv = SubprocVecEnv(fns) if cfg.vec == "subproc" and cfg.envs > 1 else DummyVecEnv(fns)
    venv.seed(cfg.seed)
    return VecMonitor(venv)


def _check_resume(out: Path, cfg: RLTrainConfig, source: dict[str, Any]) -> None:
    """Refuse to continue a run made with another action space, reward, seed or cases."""
    path = out / "config.json"
    if not path.is_file():
        return
    saved = json.loads(path.read_text())
    for name in FIXED_ON_RESUME:
        if saved["config"].get(name) != getattr(cfg, name):
            raise ConfigError(
                f"{path}: {name} = {saved['config'].get(name)!r} but this run asks for "
                f"{getattr(cfg, name)!r}; use a new --out to train another agent"
            )
    if saved.get("cases_sha256") != source["cases_sha256"]:
        raise ConfigError(f"{path}: the run was trained on other cases ({saved.get('cases')})")


def _append_log(path: Path, row: dict[str, Any]) -> None:
    new = not path.is_file()
    with path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=LOG_FIELDS)
        if new:
            writer.writeheader()
        writer.writerow({k: row.get(k, "") for k in LOG_FIELDS})


def _trim_log(path: Path, env_steps: int) -> None:
    """Drop rows written after the checkpoint a resumed run starts from."""
    if not path.is_file():
        return
    with path.open() as f:
        rows = [r for r in csv.DictReader(f) if int(float(r["env_steps"])) <= env_steps]
    path.unlink()
    for row in rows:
        _append_log(path, row)


def save_model_dir(model: Any, directory: Path, card: AgentCard) -> None:
    # A kill mid-write must not leave half a model where best/ or final/ had a whole one.
    write_atomically(directory / MODEL_FILE, model.save)
    write_card(directory, card)


def export_model_dirs(*directories: Path) -> None:
    """The ONNX export of each model directory a run wrote (``packlab export onnx``), so the
    agent plays under the policies' default runtime without torch. Done once at the end, not
    at every new best: a killed run's best/ is then refused as stale until exported."""
    for directory in directories:
        if (directory / MODEL_FILE).is_file():
            export_onnx(directory, check_states=EXPORT_CHECK_STATES)
            print(f"ONNX export: {directory / 'policy.onnx'}", flush=True)


class _Progress(BaseCallback):
    """Every ``eval_every`` steps: evaluate on the held-out cases, checkpoint, log, report; stop
    at the wall-time cap."""

    def __init__(self, run: _Run) -> None:
        super().__init__()
        self.run = run
        self.next_eval = (run.state["env_steps"] // run.cfg.eval_every + 1) * run.cfg.eval_every
        self.started = time.perf_counter()
        self.start_steps = run.state["env_steps"]

    def wall(self) -> float:
        return self.run.state_wall + time.perf_counter() - self.started

    def _on_step(self) -> bool:
        cap = self.run.cfg.minutes * 60
        over = bool(cap) and self.wall() >= cap
        if self.num_timesteps >= self.next_eval or over:
            self.next_eval += self.run.cfg.eval_every
            rate = (self.num_timesteps - self.start_steps) / max(
                time.perf_counter() - self.started, 1e-9
            )
            self.run.checkpoint(self.model, self.wall(), rate)
        return not over


class _Run:
    """The files of one run directory and what is written to them."""

    def __init__(self, cfg, out, source, held, on_log) -> None:
        self.cfg, self.out, self.source, self.held, self.on_log = cfg, out, source, held, on_log
        self.spec = FeatureSpec.default(cfg.agent, cfg.k, cfg.placement)
        state_path = out / "state.json"
        self.state: dict[str, Any] = (
            json.loads(state_path.read_text())
            if state_path.is_file() and (out / "checkpoint.zip").is_file()
            else {"env_steps": 0, "wall_s": 0.0, "best_avg": -1.0, "best": {}}
        )
        self.state_wall = float(self.state["wall_s"])
        # Once per run: the commit, the init checkpoint's digest and the selection set.
        rule = "best/: the highest held-out avg Overall at an evaluation; final/: the last"
        self.provenance = provenance(
            out, cfg.seed, init=cfg.init or None, selection=selection_record(held, rule)
        )
        self.last: dict[str, float] = {}  # scores of the latest evaluation

    def card(self, steps: int, wall: float, scores: dict[str, float]) -> AgentCard:
        return AgentCard(
            agent=self.cfg.agent,
            n_items=self.spec.n_items,
            reward=self.cfg.reward,
            env_steps=steps,
            wall_time_s=round(wall, 1),
            cores=os.cpu_count() or 0,
            cases=card_source(self.source["cases"], self.out),
            cases_sha256=self.source["cases_sha256"],
            held_out=scores,
            **self.provenance,
        )

    def log_untrained(self, model: Any) -> None:
        """Row 0 of a new run's log: the untrained agent on the held-out cases (a near-uniform
        choice, so the curve starts from its action space's random-row level)."""
        scores = evaluate(model, self.spec, self.held)
        _append_log(self.out / "log.csv", {"env_steps": 0, "wall_s": 0.0, **scores})

    def checkpoint(self, model: Any, wall: float, rate: float) -> dict[str, float]:
        steps = int(model.num_timesteps)
        scores = evaluate(model, self.spec, self.held)
        if scores["avg"] > self.state["best_avg"]:
            save_model_dir(model, self.out / "best", self.card(steps, wall, scores))
            self.state.update(best_avg=scores["avg"], best=scores)
        write_atomically(self.out / "checkpoint.zip", model.save)
        self.state.update(env_steps=steps, wall_s=wall)
        state = (json.dumps(self.state, indent=1) + "\n").encode()
        write_atomically(self.out / "state.json", lambda f: f.write(state))
        returns = [e["r"] for e in model.ep_info_buffer]
        row: dict[str, float | str] = {
            "env_steps": steps,
            "wall_s": round(wall, 1),
            "steps_per_s": round(rate, 1),
        }
        row |= {"train_return": round(float(np.mean(returns)), 4) if returns else ""}
        row |= {k: round(v, 4) for k, v in scores.items()}
        _append_log(self.out / "log.csv", row)
        self.last = scores
        print(
            f"[{self.cfg.agent}] {steps:>9,} steps  {wall / 60:6.1f} min  {rate:6.0f} steps/s  "
            f"train return {row['train_return']}  held-out avg {scores['avg']:.3f} "
            f"(best {self.state['best_avg']:.3f})",
            flush=True,
        )
        if self.on_log is not None:
            self.on_log(self.out / "log.csv", self.out / "curves.png", self.cfg.agent)
        return scores


def make_model(cfg: RLTrainConfig, venv, out: Path) -> MaskablePPO:
    """A fresh MaskablePPO agent with the item-pointer network over ``venv``."""
    tb = str(out / "tb") if importlib.util.find_spec("tensorboard") else None
    return MaskablePPO(
        ItemPointerPolicy,
        venv,
        learning_rate=cfg.lr,
        n_steps=cfg.n_steps,
        batch_size=cfg.batch,
        n_epochs=cfg.epochs,
        gamma=cfg.gamma,
        gae_lambda=cfg.gae_lambda,
        ent_coef=cfg.ent_coef,
        clip_range=cfg.clip_range,
        policy_kwargs={"features_extractor_kwargs": {"width": cfg.width}},
        tensorboard_log=tb,
        seed=cfg.seed,
        device="cpu",
        verbose=0,
    )


def load_init(model: MaskablePPO, directory: str | Path, spec: FeatureSpec) -> None:
    """Copy the network weights of the model directory ``directory`` into ``model`` (a fresh
    agent of the same action space and width): PPO then starts from, e.g., an imitation fit."""
    directory = Path(directory)
    card = read_card(directory)
    if (card.agent, card.n_items) != (spec.agent, spec.n_items):
        raise ConfigError(
            f"init = {str(directory)!r} is a {card.agent!r} agent with {card.n_items} rows; "
            f"this run trains {spec.agent!r} with {spec.n_items}"
        )
    if spec.agent == "tapnet" and card.placement != spec.placement:
        raise ConfigError(
            f"init = {str(directory)!r} places objects by {card.placement!r}; this run by "
            f"{spec.placement!r} (--placement {card.placement} continues it)"
        )
    source = MaskablePPO.load(directory / MODEL_FILE, device="cpu")
    try:
        model.policy.load_state_dict(source.policy.state_dict())
    except RuntimeError as e:
        raise ConfigError(f"init = {str(directory)!r}: another network shape ({e})") from None


def train_rl(
    cfg: RLTrainConfig,
    cases: Sequence[Case],
    source: dict[str, Any],
    on_log: Callable[[Path, Path, str], None] | None = None,
) -> RLRunResult:
    """Train (or resume) one agent; ``source`` names the cases (``cases``, ``cases_sha256``).

    ``on_log(log_csv, png, agent)`` runs after every evaluation (the CLI draws the curves).
    """
    torch.set_num_threads(cfg.threads)
    out = Path(cfg.out)
    _check_resume(out, cfg, source)
    train_cases, held = hold_out(cases, cfg.eval_cases_per_level)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(
        json.dumps({"config": cfg.to_dict(), **source}, indent=1, sort_keys=True) + "\n"
    )
    run = _Run(cfg, out, source, held, on_log)
    _trim_log(out / "log.csv", run.state["env_steps"])
    venv = make_vec_env(cfg, train_cases)
    try:
        if run.state["env_steps"]:
            model = MaskablePPO.load(out / "checkpoint.zip", env=venv, device="cpu")
            print(f"[{cfg.agent}] resuming at {run.state['env_steps']:,} steps", flush=True)
        else:
            model = make_model(cfg, venv, out)
            if cfg.init:
                load_init(model, cfg.init, run.spec)
                print(f"[{cfg.agent}] starting from {cfg.init}", flush=True)
            (out / "log.csv").unlink(missing_ok=True)  # rows of a start that never checkpointed
            run.log_untrained(model)
        callback = _Progress(run)
        left = cfg.steps - int(model.num_timesteps)
        if left > 0 and not (cfg.minutes and run.state_wall >= cfg.minutes * 60):
            model.learn(left, callback=callback, reset_num_timesteps=False)
        wall = callback.wall()
        if model.num_timesteps > run.state["env_steps"]:
            run.checkpoint(model, wall, 0.0)
        final = run.last or evaluate(model, run.spec, held)
        save_model_dir(model, out / "final", run.card(int(model.num_timesteps), wall, final))
    finally:
        venv.close()
    export_model_dirs(out / "best", out / "final")
    return RLRunResult(out, int(model.num_timesteps), wall, run.state["best"], final)
