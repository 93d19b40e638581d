"""``packlab train sft``: supervised fine-tuning of a packing VLM (needs the vlm extra)."""

from __future__ import annotations

import argparse
import json

from packlab.core.errors import PacklabError

VLM_EXTRA_HINT = (
    "the vlm extra is not installed: pip install torch==2.13.0 (CPU wheel, first), "
    "then pip install -e '.[vlm]'"
)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("train", help="train models (sft: supervised fine-tuning of the VLM)")
    sub = p.add_subparsers(dest="train_command", required=True)
    s = sub.add_parser(
        "sft",
        help="fine-tune a Qwen-VL-family model on a PackData SFT export",
        description="Step-level SFT with the loss on the answer tokens only. Multi-GPU: "
        "accelerate launch --config_file configs/accelerate/fsdp_8gpu.yaml "
        "-m packlab.cli.main train sft ...",
    )
    s.add_argument(
        "--data", required=True, help="dataset directory (reads sft/*.jsonl) or one .jsonl"
    )
    s.add_argument(
        "--model",
        default="tiny:qwen3_5:small",
        help="local checkpoint directory, or tiny:<family>:<size> for a random-weight model "
        "(families qwen3_5, qwen3_vl, qwen2_5_vl; sizes tiny, small, base)",
    )
    s.add_argument(
        "--out", required=True, help="run directory (config, loss log, curve, checkpoints)"
    )
    s.add_argument("--epochs", type=int, default=1)
    s.add_argument(
        "--lr", type=float, default=None, help="default 1e-5 for checkpoints, 1e-3 for tiny models"
    )
    s.add_argument(
        "--micro-batch", type=int, default=1, help="examples per forward pass per device"
    )
    s.add_argument(
        "--grad-accum",
        type=int,
        default=8,
        help="global batch = micro-batch x grad-accum x devices",
    )
    s.add_argument(
        "--max-length",
        type=int,
        default=4096,
        help="token limit; the oldest past steps are dropped until an example fits",
    )
    s.add_argument(
        "--max-steps", type=int, default=None, help="stop after this many optimizer steps"
    )
    s.add_argument("--warmup-ratio", type=float, default=0.03)
    s.add_argument("--weight-decay", type=float, default=0.0)
    s.add_argument("--precision", choices=("auto", "bf16", "no"), default="auto")
    s.add_argument("--gradient-checkpointing", action="store_true")
    s.add_argument(
        "--lora", action="store_true", help="train LoRA adapters (merged into the final model)"
    )
    s.add_argument("--lora-r", type=int, default=16)
    s.add_argument("--history", choices=("full", "current_only", "no_actions"), default="full")
    s.add_argument("--image", choices=("heightmap", "blank", "none"), default="heightmap")
    s.add_argument("--recipe", choices=("easy", "easy+medium", "mixed"), default="mixed")
    s.add_argument(
        "--data-fraction", type=float, default=1.0, help="fraction of episodes kept (seeded)"
    )
    s.add_argument("--seed", type=int, default=0)
    s.add_argument(
        "--template-kwargs",
        default="{}",
        help="JSON chat-template variables, e.g. '{\"enable_thinking\": false}'",
    )
    s.set_defaults(func=run_sft)


def run_sft(args: argparse.Namespace) -> int:
    from packlab.vlm.sft_config import SFTConfig

    try:
        template_kwargs = json.loads(args.template_kwargs)
    except json.JSONDecodeError as e:
        raise PacklabError(f"--template-kwargs is not JSON: {e}") from None
    cfg = SFTConfig(
        data=args.data,
        out=args.out,
        model=args.model,
        epochs=args.epochs,
        lr=args.lr,
        micro_batch=args.micro_batch,
        grad_accum=args.grad_accum,
        max_length=args.max_length,
        max_steps=args.max_steps,
        warmup_ratio=args.warmup_ratio,
        weight_decay=args.weight_decay,
        precision=args.precision,
        gradient_checkpointing=args.gradient_checkpointing,
        lora=args.lora,
        lora_r=args.lora_r,
        history=args.history,
        image=args.image,
        recipe=args.recipe,
        data_fraction=args.data_fraction,
        seed=args.seed,
        template_kwargs=template_kwargs,
    )
    try:
        from packlab.vlm.sft import train_sft
    except ModuleNotFoundError as e:
        if e.name in ("torch", "transformers", "accelerate", "peft", "tokenizers", "safetensors"):
            raise PacklabError(VLM_EXTRA_HINT) from None
        raise
    res = train_sft(cfg)
    if not res.is_main_process:
        return 0  # under accelerate/torchrun only rank 0 reports
    print(
        f"trained {res.optimizer_steps} steps on {res.n_examples} examples "
        f"in {res.wall_time_s:.0f} s; "
        f"loss {res.losses[0]:.4f} -> {res.losses[-1]:.4f}; final model: {res.final_checkpoint}"
    )
    return 0
