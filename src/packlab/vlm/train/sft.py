"""Supervised fine-tuning of a packing VLM on step-level examples (loss on the answer only).

An accelerate training loop over :func:`packlab.vlm.data.encoding.encode_fitting` examples:
AdamW, linear warmup then cosine decay, gradient accumulation to a global batch, epochs, bf16
where the hardware has it, gradient checkpointing, optional LoRA (peft). The same loop runs on one
CPU, one GPU, or several GPUs under ``accelerate launch`` (FSDP included); the model's own
cross-entropy over ``labels`` is the loss, and labels are -100 outside the answer tokens.

Writes into ``out``: ``sft_config.json`` (resolved config, prompt version, data counts),
``loss_log.jsonl`` (one line per optimizer step), ``sft_summary.json``, ``checkpoints/epoch-N``
and ``final`` (a full model directory that :func:`packlab.vlm.model.checkpoint.load_model`
reads). The loss curve (``loss_curve.png``) is drawn from ``loss_log.jsonl`` by the caller
(``packlab train sft`` uses :func:`packlab.viz.plots.plot_loss_curve`): this package draws nothing.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import torch
from accelerate import Accelerator
from accelerate.utils import set_seed
from tqdm.auto import tqdm
from transformers import get_cosine_schedule_with_warmup

from packlab.core.errors import ConfigError
from packlab.vlm.data.encoding import ProcessingConfig, collate, encode_fitting
from packlab.vlm.data.sft_examples import SFTExample, load_sft_examples, select_examples
from packlab.vlm.model.checkpoint import VLM, save_model
from packlab.vlm.model.spec import make_model
from packlab.vlm.prompt.render import PROMPT_VERSION, PromptOptions, ablate
from packlab.vlm.train.config import LORA_TARGETS, SFTConfig

__all__ = ["LOSS_LOG", "SFTResult", "train_sft"]

#: One JSON line per optimizer step: step, epoch, loss, lr, elapsed_s.
LOSS_LOG = "loss_log.jsonl"


@dataclass(frozen=True)
class SFTResult:
    out: Path
    final_checkpoint: Path
    losses: tuple[float, ...]  # mean answer-token loss per optimizer step
    n_examples: int
    optimizer_steps: int
    wall_time_s: float
    is_main_process: bool = True  # False on the other ranks of a multi-process run

    @property
    def loss_log(self) -> Path:
        """The run's loss log (written by the main process)."""
        return self.out / LOSS_LOG


class _Collator:
    """A batch of examples -> padded model inputs: each context ablated to the run's options,
    encoded with its answer, oldest past steps dropped to fit; counts the steps dropped."""

    def __init__(self, vlm: VLM, options: PromptOptions, config: ProcessingConfig) -> None:
        self.vlm, self.options, self.config = vlm, options, config
        self.dropped_steps = 0

    def __call__(self, items: list[SFTExample]) -> dict[str, torch.Tensor]:
        encoded = []
        for ex in items:
            enc, dropped = encode_fitting(
                ablate(ex.context, self.options),
                self.vlm.tokenizer,
                self.vlm.image_processor,
                answer=ex.answer,
                config=self.config,
            )
            self.dropped_steps += dropped
            encoded.append(enc)
        return collate(encoded, self.vlm.tokenizer.pad_token_id)


@dataclass
class _Run:
    """One training run's objects, as prepared by accelerate."""

    cfg: SFTConfig
    acc: Any  # accelerate.Accelerator
    vlm: VLM
    model: Any  # the prepared (possibly wrapped) model
    params: list[torch.nn.Parameter]
    optimizer: Any
    scheduler: Any
    loader: Any
    collator: _Collator
    n_examples: int
    updates_per_epoch: int
    total_updates: int
    t0: float

    @property
    def out(self) -> Path:
        return Path(self.cfg.out)


@dataclass
class _Progress:
    """What the loop accumulates: per-update losses, the current window of micro-batch losses."""

    log: TextIO | None
    bar: Any  # tqdm
    losses: list[float] = field(default_factory=list)
    step: int = 0
    window: list[float] = field(default_factory=list)


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


def _examples(
    cfg: SFTConfig, examples: list[SFTExample] | None
) -> tuple[list[SFTExample], Path | None]:
    """The examples the run trains on (the recipe and data fraction applied) and their image
    root (None when the caller passed the examples)."""
    image_root: Path | None = None
    if examples is None:
        examples, image_root = load_sft_examples(cfg.data)
    examples = select_examples(examples, cfg.recipe, cfg.data_fraction, cfg.seed)
    if not examples:
        raise ConfigError(
            f"data = {cfg.data!r}: no examples left after recipe={cfg.recipe!r}, "
            f"data_fraction={cfg.data_fraction}"
        )
    return examples, image_root


def _trainable_model(cfg: SFTConfig, vlm: VLM):
    """The model in training mode: checkpointing and LoRA applied as configured."""
    model = vlm.model
    if cfg.gradient_checkpointing:
        # The transformers the vlm extra pins names it activation checkpointing (the old
        # gradient_checkpointing_enable warns, and goes in v6).
        model.activation_checkpointing_enable(
            activation_checkpointing_kwargs={"use_reentrant": False}
        )
        model.config.use_cache = False
    if cfg.lora:
        model = _apply_lora(model, cfg)
    model.train()
    return model


def _prepare(
    cfg: SFTConfig, acc, vlm: VLM, examples: list[SFTExample], collator: _Collator, t0: float
) -> _Run:
    """Loader, optimizer and schedule, prepared by accelerate (in this order: seeds matter)."""
    model = _trainable_model(cfg, vlm)
    gen = torch.Generator().manual_seed(cfg.seed)
    loader = torch.utils.data.DataLoader(
        examples,
        batch_size=cfg.micro_batch,
        shuffle=True,  # type: ignore[arg-type]
        collate_fn=collator,
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
    return _Run(
        cfg=cfg,
        acc=acc,
        vlm=vlm,
        model=model,
        params=params,
        optimizer=optimizer,
        scheduler=scheduler,
        loader=loader,
        collator=collator,
        n_examples=len(examples),
        updates_per_epoch=updates_per_epoch,
        total_updates=total_updates,
        t0=t0,
    )


def _write_resolved_config(run: _Run) -> None:
    """``sft_config.json``: the config as resolved, the prompt version and the data counts."""
    cfg, acc = run.cfg, run.acc
    run.out.mkdir(parents=True, exist_ok=True)
    resolved = {
        **cfg.to_dict(),
        "prompt_version": PROMPT_VERSION,
        "n_examples": run.n_examples,
        "updates_per_epoch": run.updates_per_epoch,
        "total_updates": run.total_updates,
        "precision": acc.mixed_precision,
        "devices": acc.num_processes,
        "global_batch": cfg.micro_batch * cfg.grad_accum * acc.num_processes,
        "family": run.vlm.family,
    }
    (run.out / "sft_config.json").write_text(json.dumps(resolved, indent=1, sort_keys=True) + "\n")


def _save_checkpoint(run: _Run, dest: Path, final: bool) -> None:
    """A model directory at ``dest`` (LoRA: the adapter only, merged into the final model)."""
    cfg, acc, vlm = run.cfg, run.acc, run.vlm
    acc.wait_for_everyone()
    unwrapped = acc.unwrap_model(run.model)
    unwrapped.config.use_cache = True  # checkpoints are for inference; training turned it off
    if cfg.lora and final:
        unwrapped = unwrapped.merge_and_unload()  # a plain model that load_model reads
    elif cfg.lora:
        if acc.is_main_process:
            unwrapped.save_pretrained(dest / "adapter")  # intermediate LoRA: the adapter only
        return
    # Under FSDP/DeepSpeed the full weights must be gathered from every process first.
    state = (
        acc.get_state_dict(run.model)
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


def _micro_step(run: _Run, batch: dict[str, torch.Tensor], window: list[float]) -> None:
    """Forward and backward one micro-batch; the optimizer steps when accumulation is done."""
    acc = run.acc
    with acc.accumulate(run.model):
        loss = run.model(**batch).loss
        acc.backward(loss)
        window.append(loss.detach().float().item())
        if acc.sync_gradients and run.cfg.max_grad_norm > 0:
            acc.clip_grad_norm_(run.params, run.cfg.max_grad_norm)
        run.optimizer.step()
        run.scheduler.step()
        run.optimizer.zero_grad()


def _record_update(run: _Run, progress: _Progress, epoch: int) -> None:
    """Book one optimizer step: its mean loss, a loss-log line, the progress bar."""
    progress.step += 1
    mean = sum(progress.window) / len(progress.window)
    progress.window = []
    progress.losses.append(mean)
    if progress.log is not None and progress.step % run.cfg.log_every == 0:
        line = {
            "step": progress.step,
            "epoch": epoch + 1,
            "loss": round(mean, 6),
            "lr": run.scheduler.get_last_lr()[0],
            "elapsed_s": round(time.perf_counter() - run.t0, 2),
        }
        progress.log.write(json.dumps(line) + "\n")
        progress.log.flush()
    progress.bar.update(1)
    progress.bar.set_postfix(loss=f"{mean:.4f}", epoch=epoch + 1)


def _run_epoch(run: _Run, progress: _Progress, epoch: int) -> bool:
    """One pass over the loader; True when the run's optimizer-step budget is spent."""
    for batch in run.loader:
        _micro_step(run, batch, progress.window)
        if run.acc.sync_gradients:
            _record_update(run, progress, epoch)
            if progress.step >= run.total_updates:
                return True
    return False


def _train_epochs(run: _Run, progress: _Progress) -> None:
    """Every epoch (or until the step budget), with a checkpoint after each but the last."""
    cfg = run.cfg
    for epoch in range(cfg.epochs):
        done = _run_epoch(run, progress, epoch)
        if cfg.save_every_epoch and not done and epoch + 1 < cfg.epochs:
            _save_checkpoint(run, run.out / "checkpoints" / f"epoch-{epoch + 1}", final=False)
        if done:
            break


def _write_summary(run: _Run, progress: _Progress) -> None:
    summary = {
        "optimizer_steps": progress.step,
        "first_loss": progress.losses[0],
        "last_loss": progress.losses[-1],
        "history_steps_dropped_for_length": run.collator.dropped_steps,
        "wall_time_s": round(time.perf_counter() - run.t0, 2),
    }
    (run.out / "sft_summary.json").write_text(json.dumps(summary, indent=1) + "\n")


def train_sft(
    cfg: SFTConfig, examples: list[SFTExample] | None = None, progress: bool = True
) -> SFTResult:
    """Run one SFT job described by ``cfg`` (``examples`` overrides reading ``cfg.data``)."""
    t0 = time.perf_counter()
    acc = Accelerator(gradient_accumulation_steps=cfg.grad_accum, mixed_precision=_precision(cfg))
    set_seed(cfg.seed)
    examples, image_root = _examples(cfg, examples)
    options = PromptOptions(cfg.history, cfg.image)
    pcfg = ProcessingConfig(
        image_root=str(image_root) if image_root else None,
        max_length=cfg.max_length,
        template_kwargs=dict(cfg.template_kwargs),
    )
    vlm = make_model(cfg.model, cfg.seed)
    run = _prepare(cfg, acc, vlm, examples, _Collator(vlm, options, pcfg), t0)
    if acc.is_main_process:
        _write_resolved_config(run)
    log = (run.out / LOSS_LOG).open("w") if acc.is_main_process else None
    bar = tqdm(total=run.total_updates, desc="sft", disable=not (progress and acc.is_main_process))
    state = _Progress(log, bar)
    _train_epochs(run, state)
    bar.close()
    if log is not None:
        log.close()
    final = run.out / "final"
    _save_checkpoint(run, final, final=True)
    if acc.is_main_process and state.losses:
        _write_summary(run, state)
    return SFTResult(
        run.out,
        final,
        tuple(state.losses),
        len(examples),
        state.step,
        time.perf_counter() - t0,
        acc.is_main_process,
    )
