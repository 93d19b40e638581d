"""Supervised fine-tuning of a packing VLM on step-level examples (loss on the answer only).

An accelerate training loop over :func:`packlab.vlm.processing.encode_fitting` examples:
AdamW, linear warmup then cosine decay, gradient accumulation to a global batch, epochs, bf16
where the hardware has it, gradient checkpointing, optional LoRA (peft). The same loop runs on one
CPU, one GPU, or several GPUs under ``accelerate launch`` (FSDP included); the model's own
cross-entropy over ``labels`` is the loss, and labels are -100 outside the answer tokens.

Writes into ``out``: ``sft_config.json`` (resolved config, prompt version, data counts),
``loss_log.jsonl`` (one line per optimizer step), ``loss_curve.png``, ``checkpoints/epoch-N``
and ``final`` (a full model directory that :func:`packlab.vlm.model.load_model` reads).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from packlab.core.errors import ConfigError
from packlab.vlm.model import VLM, build_tiny_model, load_model, save_model
from packlab.vlm.processing import ProcessingConfig, collate, encode_fitting
from packlab.vlm.prompt import PROMPT_VERSION, PromptOptions, ablate
from packlab.vlm.sft_config import LORA_TARGETS, SFTConfig
from packlab.vlm.sft_data import SFTExample, load_sft_examples, select_examples

__all__ = ["SFTConfig", "SFTResult", "make_model", "plot_loss_curve", "train_sft"]


@dataclass(frozen=True)
class SFTResult:
    out: Path
    final_checkpoint: Path
    losses: tuple[float, ...]  # mean answer-token loss per optimizer step
    n_examples: int
    optimizer_steps: int
    wall_time_s: float
    is_main_process: bool = True  # False on the other ranks of a multi-process run


def make_model(spec: str, seed: int = 0) -> VLM:
    """``tiny:<family>:<size>`` builds a random-weight model; anything else is a checkpoint dir."""
    if spec.startswith("tiny:"):
        parts = spec.split(":")
        if len(parts) != 3:
            raise ConfigError(
                f"model = {spec!r}: expected tiny:<family>:<size>, e.g. tiny:qwen3_5:small"
            )
        return build_tiny_model(parts[1], parts[2], seed=seed)
    return load_model(spec)


def _apply_lora(model, cfg: SFTConfig):
    from peft import LoraConfig, get_peft_model

    lcfg = LoraConfig(
        r=cfg.lora_r,
        lora_alpha=cfg.lora_alpha,
        lora_dropout=cfg.lora_dropout,
        target_modules=LORA_TARGETS,
        bias="none",
    )
    return get_peft_model(model, lcfg)


def _precision(cfg: SFTConfig) -> str:
    if cfg.precision != "auto":
        return cfg.precision
    return "bf16" if torch.cuda.is_available() and torch.cuda.is_bf16_supported() else "no"


def plot_loss_curve(log_path: str | Path, png_path: str | Path, title: str = "SFT loss") -> Path:
    """Loss per optimizer step (and a moving average) from loss_log.jsonl, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [json.loads(line) for line in Path(log_path).read_text().splitlines() if line.strip()]
    steps = [r["step"] for r in rows]
    losses = [r["loss"] for r in rows]
    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=120)
    ax.plot(steps, losses, lw=0.8, alpha=0.5, label="per step")
    w = max(1, len(losses) // 20)
    if len(losses) >= 2 * w > 2:
        avg = [sum(losses[i - w + 1 : i + 1]) / w for i in range(w - 1, len(losses))]
        ax.plot(steps[w - 1 :], avg, lw=1.6, label=f"moving mean ({w})")
    ax.set_xlabel("optimizer step")
    ax.set_ylabel("answer-token NLL")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(png_path)
    plt.close(fig)
    return Path(png_path)


def train_sft(
    cfg: SFTConfig, examples: list[SFTExample] | None = None, progress: bool = True
) -> SFTResult:
    """Run one SFT job described by ``cfg`` (``examples`` overrides reading ``cfg.data``)."""
    from accelerate import Accelerator
    from accelerate.utils import set_seed
    from tqdm.auto import tqdm
    from transformers import get_cosine_schedule_with_warmup

    t0 = time.perf_counter()
    out = Path(cfg.out)
    acc = Accelerator(gradient_accumulation_steps=cfg.grad_accum, mixed_precision=_precision(cfg))
    set_seed(cfg.seed)

    image_root: Path | None = None
    if examples is None:
        examples, image_root = load_sft_examples(cfg.data)
    examples = select_examples(examples, cfg.recipe, cfg.data_fraction, cfg.seed)
    if not examples:
        raise ConfigError(
            f"data = {cfg.data!r}: no examples left after recipe={cfg.recipe!r}, "
            f"data_fraction={cfg.data_fraction}"
        )
    options = PromptOptions(cfg.history, cfg.image)  # type: ignore[arg-type]
    pcfg = ProcessingConfig(
        image_root=str(image_root) if image_root else None,
        max_length=cfg.max_length,
        template_kwargs=dict(cfg.template_kwargs),
    )

    vlm = make_model(cfg.model, cfg.seed)
    model = vlm.model
    if cfg.gradient_checkpointing:
        # transformers 5 renamed it activation checkpointing; older versions only have the old name.
        if hasattr(model, "activation_checkpointing_enable"):
            model.activation_checkpointing_enable(
                activation_checkpointing_kwargs={"use_reentrant": False}
            )
        else:
            model.gradient_checkpointing_enable(
                gradient_checkpointing_kwargs={"use_reentrant": False}
            )
        model.config.use_cache = False
    if cfg.lora:
        model = _apply_lora(model, cfg)
    model.train()

    pad_id = vlm.tokenizer.pad_token_id
    dropped_steps = [0]

    def make_batch(items: list[SFTExample]) -> dict[str, torch.Tensor]:
        encoded = []
        for ex in items:
            enc, dropped = encode_fitting(
                ablate(ex.context, options),
                vlm.tokenizer,
                vlm.image_processor,
                answer=ex.answer,
                config=pcfg,
            )
            dropped_steps[0] += dropped
            encoded.append(enc)
        return collate(encoded, pad_id)

    gen = torch.Generator().manual_seed(cfg.seed)
    loader = torch.utils.data.DataLoader(
        examples,
        batch_size=cfg.micro_batch,
        shuffle=True,  # type: ignore[arg-type]
        collate_fn=make_batch,
        generator=gen,
    )
    params = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(params, lr=cfg.resolved_lr, weight_decay=cfg.weight_decay)
    model, optimizer, loader = acc.prepare(model, optimizer, loader)
    # Counted after prepare: under several processes each one sees its shard of the loader, and
    # these are the optimizer steps every process takes (the global batch covers all of them).
    updates_per_epoch = math.ceil(len(loader) / cfg.grad_accum)
    total_updates = updates_per_epoch * cfg.epochs
    if cfg.max_steps is not None:
        total_updates = min(total_updates, cfg.max_steps)
    # accelerate advances a prepared scheduler once per process at every optimizer step, so the
    # schedule is laid out over num_processes times as many ticks.
    ticks = acc.num_processes
    scheduler = get_cosine_schedule_with_warmup(
        optimizer,
        int(cfg.warmup_ratio * total_updates) * ticks,
        max(total_updates, 1) * ticks,
    )
    scheduler = acc.prepare(scheduler)

    if acc.is_main_process:
        out.mkdir(parents=True, exist_ok=True)
        resolved = {
            **cfg.to_dict(),
            "prompt_version": PROMPT_VERSION,
            "n_examples": len(examples),
            "updates_per_epoch": updates_per_epoch,
            "total_updates": total_updates,
            "precision": acc.mixed_precision,
            "devices": acc.num_processes,
            "global_batch": cfg.micro_batch * cfg.grad_accum * acc.num_processes,
            "family": vlm.family,
        }
        (out / "sft_config.json").write_text(json.dumps(resolved, indent=1, sort_keys=True) + "\n")
    log_path = out / "loss_log.jsonl"
    log = log_path.open("w") if acc.is_main_process else None

    def checkpoint(dest: Path, final: bool) -> None:
        acc.wait_for_everyone()
        unwrapped = acc.unwrap_model(model)
        unwrapped.config.use_cache = True  # checkpoints are for inference; training turned it off
        if cfg.lora and final:
            unwrapped = unwrapped.merge_and_unload()  # a plain model that load_model reads
        elif cfg.lora:
            if acc.is_main_process:
                unwrapped.save_pretrained(dest / "adapter")  # intermediate LoRA: the adapter only
            return
        # Under FSDP/DeepSpeed the full weights must be gathered from every process first.
        state = (
            acc.get_state_dict(model)
            if acc.num_processes > 1 and not (cfg.lora and final)
            else None
        )
        if acc.is_main_process:
            save_model(
                VLM(unwrapped, vlm.tokenizer, vlm.image_processor, vlm.family, vlm.meta),
                dest,
                extra_meta={"sft_config": cfg.to_dict()},
                state_dict=state,
            )

    losses: list[float] = []
    step, window = 0, []
    bar = tqdm(total=total_updates, desc="sft", disable=not (progress and acc.is_main_process))
    done = False
    for epoch in range(cfg.epochs):
        for batch in loader:
            with acc.accumulate(model):
                loss = model(**batch).loss
                acc.backward(loss)
                window.append(loss.detach().float().item())
                if acc.sync_gradients and cfg.max_grad_norm > 0:
                    acc.clip_grad_norm_(params, cfg.max_grad_norm)
                optimizer.step()
                scheduler.step()
                optimizer.zero_grad()
            if acc.sync_gradients:
                step += 1
                mean = sum(window) / len(window)
                window = []
                losses.append(mean)
                if log is not None and step % cfg.log_every == 0:
                    log.write(
                        json.dumps(
                            {
                                "step": step,
                                "epoch": epoch + 1,
                                "loss": round(mean, 6),
                                "lr": scheduler.get_last_lr()[0],
                                "elapsed_s": round(time.perf_counter() - t0, 2),
                            }
                        )
                        + "\n"
                    )
                    log.flush()
                bar.update(1)
                bar.set_postfix(loss=f"{mean:.4f}", epoch=epoch + 1)
                if step >= total_updates:
                    done = True
                    break
        if cfg.save_every_epoch and not done and epoch + 1 < cfg.epochs:
            checkpoint(out / "checkpoints" / f"epoch-{epoch + 1}", final=False)
        if done:
            break
    bar.close()
    if log is not None:
        log.close()
    final = out / "final"
    checkpoint(final, final=True)
    if acc.is_main_process and losses:
        plot_loss_curve(
            log_path, out / "loss_curve.png", title=f"SFT {cfg.model} ({len(examples)} examples)"
        )
        summary = {
            "optimizer_steps": step,
            "first_loss": losses[0],
            "last_loss": losses[-1],
            "history_steps_dropped_for_length": dropped_steps[0],
            "wall_time_s": round(time.perf_counter() - t0, 2),
        }
        (out / "sft_summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    return SFTResult(
        out,
        final,
        tuple(losses),
        len(examples),
        step,
        time.perf_counter() - t0,
        acc.is_main_process,
    )
