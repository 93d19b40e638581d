"""Supervised fine-tuning of a packing VLM with TRL's ``SFTTrainer``.

One example is one episode (or a window of it) from the SFT export: the loss is on every
assistant turn (TRL's assistant-only loss, from the chat template's generation markers), so an
episode of T steps is encoded once for its T labelled actions. TRL and transformers do the rest:
the collator (chat template, image-token expansion, masking), the loop, AdamW with warmup and
cosine decay, gradient accumulation, bf16, gradient checkpointing, LoRA (peft), FSDP and
DeepSpeed under ``accelerate launch``, checkpoints every ``save_every`` steps, and a resume that
restores optimizer, scheduler, RNG and data position. packlab adds the data (selection,
ablations, validation split by episode), a length check that never cuts an episode silently,
a JSONL log that survives resumes, closed-loop play of generated validation cases, and a final
model directory that packlab's policies load.

Writes into ``out``: ``sft_config.json`` (resolved config, data counts), ``loss_log.jsonl``
(one line per logged step: loss, lr, grad norm; validation loss and play results when they
run), ``checkpoint-N/`` (resume points, the last ``save_total_limit`` kept), ``runs/``
(TensorBoard, where installed), ``sft_summary.json`` and ``final/`` (a full model directory;
LoRA adapters merged into the base weights).
"""

from __future__ import annotations

import importlib.util
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import torch
from transformers import TrainerCallback
from transformers.trainer_utils import IntervalStrategy, get_last_checkpoint
from trl import SFTConfig as TRLConfig
from trl import SFTTrainer

from packlab.core.choices import ModelDType
from packlab.core.errors import ConfigError
from packlab.core.types import Case
from packlab.vlm.data.sft_dataset import SFTData, load_sft_data
from packlab.vlm.model.checkpoint import VLM, load_model, save_model, torch_dtype
from packlab.vlm.model.processor import processor_for
from packlab.vlm.model.spec import make_model
from packlab.vlm.prompt.render import PROMPT_VERSION, PromptOptions
from packlab.vlm.train.closed_loop import play
from packlab.vlm.train.config import LORA_VISION_TARGETS, SFTConfig, resume_conflicts
from packlab.vlm.train.lengths import fit_lengths

__all__ = ["LOSS_LOG", "SFTResult", "resolve_dtype", "train_sft"]

#: One JSON line per logged optimizer step (and per validation or play result).
LOSS_LOG = "loss_log.jsonl"
CONFIG_FILE = "sft_config.json"


@dataclass(frozen=True)
class SFTResult:
    out: Path
    final_checkpoint: Path
    losses: tuple[float, ...]  # training loss per logged step, this run and the resumed part
    n_examples: int  # conversations trained on
    labelled_actions: int  # assistant turns in them
    dropped_examples: int  # longer than max_length under truncation="drop"
    optimizer_steps: int
    wall_time_s: float
    resumed_from: str | None
    is_main_process: bool = True  # False on the other ranks of a multi-process run

    @property
    def loss_log(self) -> Path:
        return self.out / LOSS_LOG


def resolve_dtype(name: str) -> ModelDType:
    """``auto``: bf16 on a GPU that supports it, fp32 elsewhere (CPU bf16 matmuls are slow)."""
    if name != "auto":
        return cast(ModelDType, name)
    return "bf16" if torch.cuda.is_available() and torch.cuda.is_bf16_supported() else "fp32"


def _report_to(name: str) -> list[str]:
    if name == "auto":
        return ["tensorboard"] if importlib.util.find_spec("tensorboard") else []
    if name != "none" and importlib.util.find_spec(name) is None:
        raise ConfigError(f"report_to = {name!r}: {name} is not installed (pip install {name})")
    return [] if name == "none" else [name]


def _last_checkpoint(cfg: SFTConfig) -> str | None:
    """The checkpoint to resume from, after checking that the run is the same run."""
    out = Path(cfg.out)
    last = get_last_checkpoint(str(out)) if out.is_dir() else None
    if last is None:
        return None
    saved_path = out / CONFIG_FILE
    if saved_path.is_file():
        saved = json.loads(saved_path.read_text()).get("config", {})
        conflicts = resume_conflicts(saved, cfg)
        if conflicts:
            raise ConfigError(
                f"{saved_path}: resuming {last} with other settings ({'; '.join(conflicts)}); "
                "use the run's settings or a new --out"
            )
    return last


def _trim_log(out: Path, step: int) -> None:
    """Drop log lines past ``step`` (written after the checkpoint a resume starts from)."""
    path = out / LOSS_LOG
    if not path.is_file():
        return
    kept = [ln for ln in path.read_text().splitlines() if json.loads(ln).get("step", 0) <= step]
    path.write_text("".join(ln + "\n" for ln in kept))


def _checkpoint_step(checkpoint: str) -> int:
    state = json.loads((Path(checkpoint) / "trainer_state.json").read_text())
    return int(state["global_step"])


def _load(cfg: SFTConfig, dtype: ModelDType) -> VLM:
    """The model in ``dtype``; QLoRA: a checkpoint's weights in 4-bit NF4, computing in
    ``dtype``, prepared for adapters (norms in fp32, input gradients on)."""
    if not cfg.qlora:
        return make_model(cfg.model, cfg.seed, dtype=dtype)
    if not torch.cuda.is_available() or importlib.util.find_spec("bitsandbytes") is None:
        raise ConfigError(
            "qlora = True: needs a CUDA GPU and bitsandbytes (pip install bitsandbytes)"
        )
    if cfg.is_tiny or cfg.model.startswith("config:"):
        raise ConfigError(f"qlora = True: model = {cfg.model!r}: needs a checkpoint directory")
    from peft import prepare_model_for_kbit_training
    from transformers import BitsAndBytesConfig

    quant = BitsAndBytesConfig(
        load_in_4bit=True,
        bnb_4bit_quant_type="nf4",
        bnb_4bit_use_double_quant=True,
        bnb_4bit_compute_dtype=torch_dtype(dtype),
    )
    device = f"cuda:{torch.cuda.current_device()}"
    vlm = load_model(cfg.model, dtype, device, quantization_config=quant)
    vlm.model = prepare_model_for_kbit_training(vlm.model, cfg.gradient_checkpointing)
    return vlm


def _freeze_vision(model: Any) -> int:
    """Full fine-tuning without ``train_vision``: the vision tower keeps its weights."""
    n = 0
    for name, p in model.named_parameters():
        if ".visual." in f".{name}":
            p.requires_grad_(False)
            n += p.numel()
    return n


def _peft_config(cfg: SFTConfig) -> Any:
    from peft import LoraConfig

    targets = cfg.lora_targets
    if cfg.train_vision:
        targets = f"({targets})|({LORA_VISION_TARGETS})"
    return LoraConfig(
        r=cfg.lora_r,
        lora_alpha=cfg.lora_alpha,
        lora_dropout=cfg.lora_dropout,
        target_modules=targets,
        bias="none",
        task_type="CAUSAL_LM",
    )


def _trl_args(cfg: SFTConfig, dtype: ModelDType, has_val: bool, progress: bool) -> TRLConfig:
    """The trainer's arguments; ``max_length`` is set once the examples are measured."""
    return TRLConfig(
        output_dir=cfg.out,
        num_train_epochs=cfg.epochs,
        max_steps=cfg.max_steps or -1,
        per_device_train_batch_size=cfg.micro_batch,
        per_device_eval_batch_size=cfg.micro_batch,
        gradient_accumulation_steps=cfg.grad_accum,
        learning_rate=cfg.resolved_lr,
        lr_scheduler_type="cosine",
        warmup_steps=cfg.warmup_ratio,  # a float below 1 is a fraction of the run
        weight_decay=cfg.weight_decay,
        max_grad_norm=cfg.max_grad_norm,
        bf16=dtype == "bf16",
        fp16=dtype == "fp16",
        # transformers 5 names gradient checkpointing "activation checkpointing".
        activation_checkpointing=cfg.gradient_checkpointing,
        activation_checkpointing_kwargs={"use_reentrant": False},
        logging_steps=cfg.log_every,
        save_strategy="steps",
        save_steps=cfg.save_every,
        save_total_limit=cfg.save_total_limit,
        eval_strategy="steps" if has_val else "no",
        eval_steps=cfg.eval_every,
        seed=cfg.seed,
        data_seed=cfg.seed,
        dataloader_num_workers=cfg.workers,
        report_to=_report_to(cfg.report_to),
        assistant_only_loss=True,
        # Vision rows are encoded by the collator in the DataLoader (workers, not up front).
        dataset_kwargs={"skip_prepare_dataset": True},
        remove_unused_columns=False,
        disable_tqdm=not progress,
        use_cpu=not torch.cuda.is_available(),
    )


class _JsonLog(TrainerCallback):
    """Appends every log record (train loss, validation loss) to ``loss_log.jsonl``."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def write(self, step: int, epoch: float | None, record: dict[str, Any]) -> None:
        line = {"step": step, "epoch": round(epoch or 0.0, 4), **record}
        with self.path.open("a") as fh:
            fh.write(json.dumps(line) + "\n")

    def on_log(self, args: Any, state: Any, control: Any, logs: Any = None, **kw: Any) -> None:
        if state.is_world_process_zero and logs:
            self.write(state.global_step, state.epoch, logs)


class _Play(TrainerCallback):
    """Plays the validation cases every ``every`` steps and at the end. The result goes to the
    JSONL log, the trainer's log history and TensorBoard, as its own record (logging it through
    ``Trainer.log`` mid-step would take the place of that step's loss record)."""

    def __init__(
        self, cfg: SFTConfig, vlm: VLM, cases: list[Case], image_size: int, log: _JsonLog
    ) -> None:
        self.cfg, self.vlm, self.cases, self.image_size, self.log = cfg, vlm, cases, image_size, log
        self.trainer: Any = None
        self.last_step = -1

    def _run(self, state: Any, model: Any) -> None:
        if state.global_step == self.last_step or not state.is_world_process_zero:
            return
        self.last_step = state.global_step
        result = play(
            model,
            self.vlm,
            self.cases,
            PromptOptions(self.cfg.history, self.cfg.image),
            self.image_size,
            self.cfg.play_backend,
            dict(self.cfg.template_kwargs),
        ).to_dict()
        self.log.write(state.global_step, state.epoch, result)
        state.log_history.append({**result, "step": state.global_step})
        for cb in self.trainer.callback_handler.callbacks:
            writer = getattr(cb, "tb_writer", None)
            if writer is not None:
                for k, v in result.items():
                    writer.add_scalar(f"play/{k}", v, state.global_step)

    def on_step_end(self, args: Any, state: Any, control: Any, model: Any = None, **kw: Any):
        if state.global_step % self.cfg.play_every == 0:
            self._run(state, model)

    def on_train_end(self, args: Any, state: Any, control: Any, model: Any = None, **kw: Any):
        self._run(state, model)


def _image_size(data: SFTData) -> int:
    """The side of the export's images (the renderer must draw the same for play)."""
    for images in data.train["images"]:
        if images:
            return int(images[0].size[0])
    return 224


def _write_config(cfg: SFTConfig, out: Path, extra: dict[str, Any]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    resolved = {"config": cfg.to_dict(), "prompt_version": PROMPT_VERSION, **extra}
    (out / CONFIG_FILE).write_text(json.dumps(resolved, indent=1, sort_keys=True) + "\n")


def _save_final(trainer: Any, cfg: SFTConfig, vlm: VLM, dtype: ModelDType, final: Path) -> None:
    """``final``: a full model directory. Under FSDP or DeepSpeed ``save_model`` gathers the
    shards; LoRA adapters are saved, then merged into a freshly loaded base on the main process
    (merging the wrapped, sharded model in place would merge into one shard)."""
    meta = {"sft_config": cfg.to_dict(), "action_format": "json"}
    if not cfg.lora:
        trainer.save_model(str(final))
        if trainer.is_world_process_zero():
            model = trainer.accelerator.unwrap_model(trainer.model)
            model.config.use_cache = True  # checkpoints are for inference
            bundle = VLM(model, vlm.tokenizer, vlm.image_processor, vlm.family, vlm.meta)
            save_model(bundle, final, extra_meta=meta, weights=False)
        return
    adapter = final.parent / "adapter"
    trainer.save_model(str(adapter))
    if not trainer.is_world_process_zero():
        return
    from peft import PeftModel

    base = make_model(cfg.model, cfg.seed, dtype=dtype)
    merged = PeftModel.from_pretrained(base.model, str(adapter)).merge_and_unload()
    merged.config.use_cache = True
    bundle = VLM(merged, vlm.tokenizer, vlm.image_processor, vlm.family, vlm.meta)
    save_model(bundle, final, extra_meta=meta)


def _losses(out: Path) -> tuple[float, ...]:
    path = out / LOSS_LOG
    if not path.is_file():
        return ()
    lines = [json.loads(ln) for ln in path.read_text().splitlines()]
    return tuple(float(x["loss"]) for x in lines if "loss" in x)


def _trainer(
    cfg: SFTConfig,
    vlm: VLM,
    processor: Any,
    data: SFTData,
    args: TRLConfig,
    play_cases: list[Case] | None,
) -> Any:
    """TRL's trainer with packlab's callbacks (JSON log, closed-loop play)."""
    json_log = _JsonLog(Path(cfg.out) / LOSS_LOG)
    callbacks: list[Any] = [json_log]
    player = None
    if play_cases and args.world_size > 1:
        # A sharded model (FSDP, ZeRO-3) cannot run a forward pass on one process alone.
        print(
            f"closed-loop play is off across {args.world_size} processes: play the saved "
            "checkpoints with packlab bench",
            file=sys.stderr,
        )
    elif play_cases:
        player = _Play(cfg, vlm, play_cases, _image_size(data), json_log)
        callbacks.append(player)
    trainer = SFTTrainer(
        model=vlm.model,
        args=args,
        train_dataset=data.train,
        eval_dataset=data.val,
        processing_class=processor,
        peft_config=_peft_config(cfg) if cfg.lora else None,
        callbacks=callbacks,
    )
    if player is not None:
        player.trainer = trainer
    return trainer


def _write_summary(result: SFTResult, counts: dict[str, Any]) -> None:
    summary = {
        "optimizer_steps": result.optimizer_steps,
        "first_loss": result.losses[0],
        "last_loss": result.losses[-1],
        "resumed_from": result.resumed_from,
        "wall_time_s": round(result.wall_time_s, 2),
        **counts,
    }
    (result.out / "sft_summary.json").write_text(json.dumps(summary, indent=1) + "\n")


def train_sft(
    cfg: SFTConfig, play_cases: list[Case] | None = None, progress: bool = True
) -> SFTResult:
    """Run (or resume) the SFT job described by ``cfg``; ``play_cases`` are the generated
    validation cases the model plays (``cfg.play_cases`` per level, made by the caller)."""
    t0 = time.perf_counter()
    out = Path(cfg.out)
    resume = _last_checkpoint(cfg)
    dtype = resolve_dtype(cfg.dtype)
    options = PromptOptions(cfg.history, cfg.image)
    data = load_sft_data(
        cfg.data, options, cfg.recipe, cfg.data_fraction, cfg.val_fraction, cfg.seed
    )
    args = _trl_args(cfg, dtype, data.val is not None, progress)
    # Reading args.device sets up the process group before the weights load: under FSDP with
    # cpu-RAM-efficient loading, transformers then reads the checkpoint on rank 0 only.
    _ = args.device
    vlm = _load(cfg, dtype)
    processor = processor_for(vlm)
    fitted = fit_lengths(data, processor, cfg.max_length, cfg.truncation, cfg.template_kwargs)
    data = fitted.data
    args.max_length = fitted.max_length
    if data.val is None:
        args.eval_strategy = IntervalStrategy.NO
    frozen = 0 if (cfg.lora or cfg.train_vision) else _freeze_vision(vlm.model)
    trainer = _trainer(cfg, vlm, processor, data, args, play_cases)
    counts = {
        "dtype": dtype,
        "devices": trainer.accelerator.num_processes,
        "global_batch": cfg.micro_batch * cfg.grad_accum * trainer.accelerator.num_processes,
        "train_examples": len(data.train),
        "train_labelled_actions": SFTData.labelled_actions(data.train),
        "val_examples": len(data.val) if data.val is not None else 0,
        "max_length": fitted.max_length,
        "dropped_for_length": fitted.dropped,
        "frozen_vision_parameters": frozen,
        "family": vlm.family,
    }
    if trainer.is_world_process_zero():
        _write_config(cfg, out, counts)
        if resume is not None:
            _trim_log(out, _checkpoint_step(resume))
        else:
            (out / LOSS_LOG).unlink(missing_ok=True)
    trainer.train(resume_from_checkpoint=resume)
    final = out / "final"
    _save_final(trainer, cfg, vlm, dtype, final)
    result = SFTResult(
        out=out,
        final_checkpoint=final,
        losses=_losses(out),
        n_examples=len(data.train),
        labelled_actions=counts["train_labelled_actions"],
        dropped_examples=fitted.dropped,
        optimizer_steps=trainer.state.global_step,
        wall_time_s=time.perf_counter() - t0,
        resumed_from=resume,
        is_main_process=trainer.is_world_process_zero(),
    )
    if result.is_main_process and result.losses:
        _write_summary(result, counts)
    _leave_process_group()
    return result


def _leave_process_group() -> None:
    """Close a multi-process run's process group once every rank is done. Left to interpreter
    exit, gloo's threads can abort the rank that exits first ("terminate called without an
    active exception", exit code -6), and torchrun then fails the whole run after it wrote its
    model."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()
