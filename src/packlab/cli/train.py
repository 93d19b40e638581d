"""``packlab train sft``: supervised fine-tuning of a packing VLM (needs the vlm extra)."""

from __future__ import annotations

import argparse
import json
from functools import partial
from pathlib import Path
from typing import Any

from packlab.bench.suites import resolve_cases
from packlab.cli.options import add_field, config_kwargs
from packlab.cli.train_rl import register_rl
from packlab.core.errors import PacklabError
from packlab.datagen.format import INFO_FILE
from packlab.datagen.guard import require_training_cases
from packlab.datagen.stats import dataset_cases
from packlab.policies.listed import TEACHERS
from packlab.viz.plots import plot_loss_curve
from packlab.viz.pointer_curves import write_curves
from packlab.vlm.candidate.recipe import DAGGER_MODULE, DaggerConfig
from packlab.vlm.data.sft_examples import RECIPES
from packlab.vlm.extra import VLM_EXTRA_HINT, import_torch_side, missing_extra
from packlab.vlm.train.config import LR_PRETRAINED, LR_TINY, SFTConfig

#: The trainer's module (vlm extra), imported when the command runs.
TRAINER_MODULE = "packlab.vlm.train.sft"


def _template_kwargs(text: str) -> dict[str, Any]:
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise PacklabError(f"--template-kwargs is not JSON: {e}") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="train_command", required=True)
    s = sub.add_parser(
        "sft",
        help="fine-tune a Qwen-VL-family model on a PackData SFT export",
        description="Step-level SFT with the loss on the answer tokens only. Multi-GPU: "
        "accelerate launch --config_file configs/accelerate/fsdp_8gpu.yaml "
        "-m packlab.cli.main train sft ...",
    )
    field = partial(add_field, s, SFTConfig)
    field(
        "data", "--data", required=True, help="dataset directory (reads sft/*.jsonl) or one .jsonl"
    )
    field(
        "model",
        "--model",
        help="local checkpoint directory, or tiny:<family>:<size> for a random-weight model "
        "(families qwen3_5, qwen3_vl, qwen2_5_vl; sizes tiny, small, base); "
        "default {default}",
    )
    field(
        "out", "--out", required=True, help="run directory (config, loss log, curve, checkpoints)"
    )
    field("epochs", "--epochs", help="default {default}")
    field(
        "lr", "--lr", help=f"default {LR_PRETRAINED:g} for checkpoints, {LR_TINY:g} for tiny models"
    )
    field(
        "micro_batch",
        "--micro-batch",
        help="examples per forward pass per device; default {default}",
    )
    field(
        "grad_accum",
        "--grad-accum",
        help="global batch = micro-batch x grad-accum x devices; default {default}",
    )
    field(
        "max_length",
        "--max-length",
        help="token limit; the oldest past steps are dropped until an example fits; "
        "default {default}",
    )
    field("max_steps", "--max-steps", help="stop after this many optimizer steps")
    field("warmup_ratio", "--warmup-ratio", help="default {default}")
    field("weight_decay", "--weight-decay", help="default {default}")
    field("precision", "--precision", help="default {default}")
    field("gradient_checkpointing", "--gradient-checkpointing")
    field("lora", "--lora", help="train LoRA adapters (merged into the final model)")
    field("lora_r", "--lora-r", help="default {default}")
    field("history", "--history", help="default {default}")
    field("image", "--image", help="default {default}")
    field("recipe", "--recipe", choices=tuple(RECIPES), help="default {default}")
    field(
        "data_fraction",
        "--data-fraction",
        help="fraction of episodes kept (seeded); default {default}",
    )
    field("seed", "--seed", help="default {default}")
    field(
        "template_kwargs",
        "--template-kwargs",
        parse=_template_kwargs,
        help="JSON chat-template variables, e.g. '{\"enable_thinking\": false}'",
    )
    s.set_defaults(func=run_sft)
    register_candidate(sub)
    register_rl(sub)


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


def check_sft_data(data: str) -> None:
    """Refuse SFT data whose episodes are bench cases, by the cases' seeds: the episodes of the
    PackData directory at or above ``data`` (``meta/info.json``). A loose JSONL outside any
    dataset carries no case seeds and is not checked (``packlab generate`` writes every SFT
    export inside its dataset, in the train seed domain)."""
    p = Path(data)
    start = p if p.is_dir() else p.parent
    root = next((d for d in (start, *start.parents) if (d / INFO_FILE).is_file()), None)
    if root is not None:
        require_training_cases(dataset_cases(root), f"dataset {str(root)!r}")


def run_sft(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    check_sft_data(cfg.data)
    trainer = _torch_side(TRAINER_MODULE)
    res = trainer.train_sft(cfg)
    if not res.is_main_process:
        return 0  # under accelerate/torchrun only rank 0 reports
    if res.losses:
        title = f"SFT {cfg.model} ({res.n_examples} examples)"
        plot_loss_curve(res.loss_log, res.out / "loss_curve.png", title=title)
    print(
        f"trained {res.optimizer_steps} steps on {res.n_examples} examples "
        f"in {res.wall_time_s:.0f} s; "
        f"loss {res.losses[0]:.4f} -> {res.losses[-1]:.4f}; final model: {res.final_checkpoint}"
    )
    return 0


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
    field("k", "--k", help="placements listed per state; default {default}")
    field("shuffle", "--no-shuffle", help="ablation: list placements in the proposer's order")
    field("pool", "--pool", choices=("last", "mean"), help="default {default}")
    field("batch", "--batch", help="default {default}")
    field("lr", "--lr", help="default {default}")
    field("workers", "--workers", help="collection processes; default {default}")
    field("seed", "--seed", help="default {default}")
    field("minutes_per_round", "--minutes-per-round", help="cap on each round's training")
    field("threads", "--threads", help="torch threads for training; default torch's")
    c.set_defaults(func=run_candidate)


def run_candidate(args: argparse.Namespace) -> int:
    cfg = DaggerConfig(**config_kwargs(args, "train candidate", DaggerConfig))
    source = resolve_cases(args.cases)
    cases = require_training_cases(source.cases, source.origin)
    dagger = _torch_side(DAGGER_MODULE)
    final = dagger.run_dagger(cfg, cases, write_curves)
    print(f"final model: {final} (log and curves under {cfg.out}/r*/train)")
    return 0
