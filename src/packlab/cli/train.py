"""``packlab train``: ``sft`` (supervised fine-tuning of a packing VLM, vlm extra), ``candidate``
(a pointer model: teacher rollouts, then DAgger), ``rl`` and ``rl-imitate`` (the RL baselines,
rl extra).

This module holds their flags; what they do is :mod:`packlab.cli.train_run` (sft, candidate) and
:mod:`packlab.cli.train_rl` (rl, rl-imitate), imported when one runs.
"""

from __future__ import annotations

import argparse
import importlib
import json
from functools import partial
from typing import Any

from packlab.cli.options import add_field, config_kwargs
from packlab.core.choices import TEACHERS
from packlab.core.errors import PacklabError
from packlab.rl.config import ImitationConfig, RLTrainConfig
from packlab.vlm.candidate.recipe import DaggerConfig
from packlab.vlm.data.sft_dataset import RECIPES
from packlab.vlm.extra import VLM_EXTRA_HINT, import_torch_side, missing_extra
from packlab.vlm.train.config import (
    DTYPES,
    LR_PRETRAINED,
    LR_TINY,
    REPORTERS,
    TRUNCATIONS,
    SFTConfig,
)

#: What ``train sft`` and ``train candidate`` do (data checks, curves), and what ``train rl``
#: and ``train rl-imitate`` do: imported when one runs.
RUN_MODULE = "packlab.cli.train_run"
RL_RUN_MODULE = "packlab.cli.train_rl"


def _template_kwargs(text: str) -> dict[str, Any]:
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise PacklabError(f"--template-kwargs is not JSON: {e}") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="train_command", required=True)
    register_sft(sub)
    register_candidate(sub)
    register_rl(sub)


def register_sft(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser(
        "sft",
        help="fine-tune a Qwen-VL-family model on a PackData SFT export (TRL)",
        description="One conversation per episode, the loss on every answer. Rerun the same "
        "command to resume from the last checkpoint. Several GPUs: accelerate launch "
        "--config_file configs/accelerate/fsdp_8gpu.yaml -m packlab.cli.main train sft ...",
    )
    field = partial(add_field, s, SFTConfig)
    field(
        "data",
        "--data",
        required=True,
        help="a dataset directory (its sft/*.parquet), an export directory or one .parquet",
    )
    field(
        "model",
        "--model",
        help="a local checkpoint directory, config:PATH (random weights of a config.json), or "
        "tiny:<family>:<size> (families qwen3_5, qwen3_vl, qwen2_5_vl; sizes tiny, mini, "
        "small, base); default {default}",
    )
    field("out", "--out", required=True, help="run directory (config, log, checkpoints, final)")
    field("dtype", "--dtype", choices=DTYPES, help="weights as loaded; default {default}")
    field("epochs", "--epochs", help="default {default}")
    field(
        "lr", "--lr", help=f"default {LR_PRETRAINED:g} for checkpoints, {LR_TINY:g} for tiny models"
    )
    field("micro_batch", "--micro-batch", help="episodes per forward pass per device; {default}")
    field(
        "grad_accum",
        "--grad-accum",
        help="global batch = micro-batch x grad-accum x devices; default {default}",
    )
    field(
        "max_length",
        "--max-length",
        help="tokens per example; default: the longest example's",
    )
    field(
        "truncation",
        "--truncation",
        choices=TRUNCATIONS,
        help="an example over --max-length: error (stop before training) or drop (counted); "
        "default {default}",
    )
    field("max_steps", "--max-steps", help="stop after this many optimizer steps")
    field("warmup_ratio", "--warmup-ratio", help="default {default}")
    field("weight_decay", "--weight-decay", help="default {default}")
    field("gradient_checkpointing", "--gradient-checkpointing")
    field("lora", "--lora", help="train LoRA adapters (merged into the final model)")
    field("qlora", "--qlora", help="LoRA on 4-bit base weights (CUDA, bitsandbytes)")
    field("lora_r", "--lora-r", help="default {default}")
    field("lora_alpha", "--lora-alpha", help="default {default}")
    field("lora_dropout", "--lora-dropout", help="default {default}")
    field("lora_targets", "--lora-targets", help="module-name regex; default: LLM projections")
    field(
        "train_vision",
        "--train-vision",
        help="the vision tower trains too (LoRA: adapted); default frozen",
    )
    _sft_data_and_eval_flags(s)
    s.set_defaults(func=run_sft)


def _sft_data_and_eval_flags(s: argparse.ArgumentParser) -> None:
    """``train sft``'s flags for the data, its ablations, evaluation, saving and logging."""
    field = partial(add_field, s, SFTConfig)
    field("history", "--history", help="default {default}")
    field("image", "--image", help="default {default}")
    field("recipe", "--recipe", choices=tuple(RECIPES), help="default {default}")
    field(
        "data_fraction",
        "--data-fraction",
        help="fraction of episodes kept (seeded); default {default}",
    )
    field("val_fraction", "--val-fraction", help="episodes held out for validation; {default}")
    field("save_every", "--save-every", help="optimizer steps between checkpoints; {default}")
    field("save_total_limit", "--save-total-limit", help="checkpoints kept; default {default}")
    field("eval_every", "--eval-every", help="steps between validation losses; {default}")
    field(
        "play_cases",
        "--play-cases",
        help="generated validation cases per level the model plays closed loop (0: none); "
        "default {default}",
    )
    field("play_every", "--play-every", help="steps between plays; default {default}")
    field("play_backend", "--play-backend", help="default {default}")
    field("workers", "--workers", help="DataLoader worker processes; default {default}")
    field("report_to", "--report-to", choices=REPORTERS, help="default {default}")
    field("seed", "--seed", help="default {default}")
    field(
        "template_kwargs",
        "--template-kwargs",
        parse=_template_kwargs,
        help="JSON chat-template variables, e.g. '{\"enable_thinking\": false}'",
    )


def _torch_side(module: str):
    """A trainer module of the vlm extra, or the install hint when the extra is missing."""
    try:
        return import_torch_side(module)
    except ModuleNotFoundError as e:
        if missing_extra(e):
            raise PacklabError(VLM_EXTRA_HINT) from None
        raise


def config_from_args(args: argparse.Namespace) -> SFTConfig:
    """The SFTConfig the flags describe; a flag left out leaves the field's default."""
    return SFTConfig(**config_kwargs(args, "train sft", SFTConfig))


def register_candidate(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser(
        "candidate",
        help="train a candidate-mode pointer model: teacher rollouts, then DAgger rounds",
        description="Round 0 labels the teacher's own trajectories; each later round plays new "
        "cases with the current model and labels the states it reaches. Rerun to resume.",
    )
    field = partial(add_field, c, DaggerConfig)
    c.add_argument("--cases", required=True, help="generated training cases (packlab generate)")
    field("out", "--out", required=True, help="run directory (states, logs, models)")
    field("teacher", "--teacher", choices=TEACHERS, help="default {default}")
    field("rounds", "--rounds", help="DAgger rounds after round 0; default {default}")
    field("cases_per_round", "--cases-per-round", help="default {default}")
    field("eval_cases_per_level", "--eval-cases", help="per level; default {default}")
    field("steps", "--steps", help="round 0's updates; default {default}")
    field("round_steps", "--round-steps", help="each later round's updates; default {default}")
    field("model", "--model", help="tiny:<family>:<size> or a pointer directory; {default}")
    field("instructions", "--instructions", help="default {default}")
    field("map", "--map", help="how the model sees the heightmap; default {default}")
    field("blank_map", "--blank-map", help="ablation: the map shows an empty container")
    field(
        "line_vectors",
        "--no-line-vectors",
        help="ablation: the head reads the lines' hidden states only, no line vectors",
    )
    field(
        "line_fields",
        "--line-fields",
        help="what each listed line names: full (with z, support, flushness, gap) or cell "
        "(box, rotation, cell only); default {default}",
    )
    field("image_tokens", "--image-tokens", help="image tokens per side; default {default}")
    field(
        "footprint_pool",
        "--footprint-pool",
        help="the head also pools the image tokens under each line's footprint (torch only)",
    )
    field(
        "footprint_context",
        "--footprint-context",
        help="with --footprint-pool: the head also reads the max over the footprint's image "
        "tokens and the mean over the one-token ring around it (torch only)",
    )
    field("k", "--k", help="placements listed per state; default {default}")
    field("shuffle", "--no-shuffle", help="ablation: list placements in the proposer's order")
    field("pool", "--pool", choices=("last", "mean"), help="default {default}")
    field("batch", "--batch", help="default {default}")
    field("lr", "--lr", help="default {default}")
    field("workers", "--workers", help="collection processes; default {default}")
    field("seed", "--seed", help="default {default}")
    field("minutes_per_round", "--minutes-per-round", help="cap on each round's training")
    field("threads", "--threads", help="torch threads for training; default torch's")
    field(
        "device",
        "--device",
        help="where training and its evaluations run: auto (a GPU when torch sees one), cpu, "
        "cuda or cuda:<index>; default {default}",
    )
    field(
        "dtype",
        "--dtype",
        help="bf16: forward passes under bf16 autocast on a GPU, weights and optimizer fp32; "
        "default {default}",
    )
    c.set_defaults(func=run_candidate)


def register_rl(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser(
        "rl",
        help="train an RL baseline: irbpp (pick a listed placement) or tapnet (pick the object)",
        description="MaskablePPO (sb3-contrib) on the geometric backend, one agent over all "
        "levels; held-out evaluation, checkpoints, log.csv and curves.png under --out. "
        "Rerun the same command to resume.",
    )
    field = partial(add_field, r, RLTrainConfig)
    field("agent", "--agent", help="default {default}")
    r.add_argument(
        "--cases",
        default="packdata-20k",
        help="a dataset recipe (generated now) or generated cases on disk; default %(default)s",
    )
    field("steps", "--steps", help="env steps in total; default {default}")
    field("out", "--out", help="run directory; default {default}")
    field("minutes", "--minutes", help="wall-time cap across resumes (0: none)")
    field("envs", "--envs", help="environment copies; default {default}")
    field("vec", "--vec", help="default {default}")
    field("reward", "--reward", help="default {default}")
    field("k", "--k", help="irbpp: placements listed per step; default {default}")
    field("n_steps", "--n-steps", help="steps per env per rollout; default {default}")
    field("batch", "--batch", help="default {default}")
    field("epochs", "--epochs", help="default {default}")
    field("lr", "--lr", help="default {default}")
    field("gamma", "--gamma", help="default {default}")
    field("ent_coef", "--ent-coef", help="default {default}")
    field("width", "--width", help="default {default}")
    field("eval_every", "--eval-every", help="env steps; default {default}")
    field("eval_cases_per_level", "--eval-cases", help="held out per level; default {default}")
    field("seed", "--seed", help="default {default}")
    field("threads", "--threads", help="torch threads of the learner; default {default}")
    field("init", "--init", help="a model directory to start from (e.g. rl-imitate's --out)")
    field(
        "placement",
        "--placement",
        help="tapnet: the rule placing the chosen box; default {default}",
    )
    r.set_defaults(func=run_rl)
    register_rl_imitate(sub)


def register_rl_imitate(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser(
        "rl-imitate",
        help="behaviour-clone an RL agent (irbpp or tapnet) from planner-labelled states",
        description="Fit the agent's actor to a teacher's picks in candidate-mode states "
        "(JSONL, packlab.vlm.candidate.states) and save a model directory that packlab bench "
        "plays (--policy-arg irbpp:model=DIR) and packlab train rl --init DIR continues.",
    )
    field = partial(add_field, r, ImitationConfig)
    field("agent", "--agent", help="default {default}")
    r.add_argument("--states", required=True, help="labelled states (JSONL)")
    r.add_argument(
        "--cases",
        default=None,
        help="the generated cases the states come from (recipe or path), checked by their "
        "seeds; without it, the states' case ids must be training-domain ids (train-...)",
    )
    field("out", "--out", help="model directory; default {default}")
    field(
        "init",
        "--init",
        help="a model directory to start from (a DAgger round on a trained agent: "
        "src/packlab/data/models/irbpp, a PPO run's final); default: fresh weights",
    )
    for name in ("k", "width", "epochs", "batch", "lr", "value_weight", "seed", "threads"):
        field(name, "--" + name.replace("_", "-"), help="default {default}")
    field(
        "placement",
        "--placement",
        help="tapnet: the rule placing the chosen box; default {default}",
    )
    r.set_defaults(func=run_rl_imitate)


def check_sft_data(data: str) -> None:
    """Refuse SFT data holding bench cases (:func:`packlab.cli.train_run.check_sft_data`)."""
    importlib.import_module(RUN_MODULE).check_sft_data(data)


def run_sft(args: argparse.Namespace) -> int:
    """``packlab train sft``."""
    return int(importlib.import_module(RUN_MODULE).run_sft(args))


def run_candidate(args: argparse.Namespace) -> int:
    """``packlab train candidate``."""
    return int(importlib.import_module(RUN_MODULE).run_candidate(args))


def run_rl(args: argparse.Namespace) -> int:
    """``packlab train rl``."""
    return int(importlib.import_module(RL_RUN_MODULE).run_rl(args))


def run_rl_imitate(args: argparse.Namespace) -> int:
    """``packlab train rl-imitate``."""
    return int(importlib.import_module(RL_RUN_MODULE).run_rl_imitate(args))
