"""Training a pointer model on labelled states: seeded, resumable, evaluated while it trains.

Held-out states are those of every tenth case (by a hash of the case id), never trained on.
Every ``eval_every`` updates the log (``log.csv``) gets the held-out answer NLL (nats; the
answer has one field, the index), its exact match, the same for two baselines (the label's
marginal distribution over list positions, and always index 0), and the closed-loop Overall of
the model on held-out generated cases (geometric backend), and ``curves.png`` is redrawn. A
checkpoint (model, optimizer, schedule, step) is written at the same time; a rerun with the same
``out`` resumes from it. Batches are drawn by a generator seeded with (seed, step), so a resumed
run draws the same batches as an uninterrupted one.
Imports torch: only the vlm extra may import this module.
"""

from __future__ import annotations

import math
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from packlab.core.choices import AutocastDType, LineFields, PointerMap, require_choice
from packlab.core.errors import ConfigError
from packlab.core.types import Case
from packlab.policies.candidates import STUDENT_K, ProposerConfig
from packlab.policies.provenance import card_path, provenance, selection_record
from packlab.vlm.candidate.compose import Answer, Instructions
from packlab.vlm.candidate.device import autocast, placement
from packlab.vlm.candidate.encoding import Extras, PromptSettings, settings_grid
from packlab.vlm.candidate.evaluate import Heldout, closed_loop, heldout_metrics
from packlab.vlm.candidate.files import is_pointer_dir
from packlab.vlm.candidate.image import TOKENS_PER_SIDE
from packlab.vlm.candidate.onnx_export import export_onnx
from packlab.vlm.candidate.pointer import (
    QWEN3_GRID,
    Encoded,
    ImageGrid,
    PointerModel,
    collate,
    encode,
    soft_loss,
    to_device,
)
from packlab.vlm.candidate.precision import check_device, check_dtype
from packlab.vlm.candidate.recipe import check_model_view
from packlab.vlm.candidate.saved import load_pointer, save_pointer
from packlab.vlm.candidate.states import read_states, shuffled
from packlab.vlm.model.spec import make_model

CHECKPOINT = "checkpoint.pt"
LOG = "log.csv"


@dataclass(frozen=True)
class PointerTrainConfig:
    states: tuple[str, ...]  # states.jsonl files
    out: str
    model: str = "tiny:qwen3_vl:mini"  # a tiny spec, or a pointer directory to start from
    instructions: Instructions = "short"
    blank_map: bool = False  # zero the heightmap in whatever form ``map`` shows it
    #: How the heightmap is shown: image (vision tower), text (digit map), both, blank (an
    #: all-zero image). A pointer directory in ``model`` must have been trained with this map.
    map: PointerMap = "image"
    pool: str = "last"  # pointer.POOLS
    #: The head also reads each listed line's numeric vector (pointer.LineHead).
    line_vectors: bool = True
    #: What each listed line names: full geometry, or its cell only (compose.cell_line).
    line_fields: LineFields = "full"
    #: Merged visual tokens per image side (image maps; the card's ``image_tokens``).
    image_tokens: int = TOKENS_PER_SIDE
    #: The head also reads the visual tokens under each line's footprint (pointer module
    #: docstring; image maps; plays under torch only, no ONNX export).
    footprint_pool: bool = False
    #: With ``footprint_pool``: the head also reads the max over the footprint's tokens and the
    #: mean over the one-token ring around it (pointer module docstring).
    footprint_context: bool = False
    #: Placements the states list (the proposer's K the policy will list at play time).
    k: int = STUDENT_K
    answer: Answer = "index"  # pointer over the listed lines, or free JSON tokens
    shuffle: bool = False  # list the placements in a random order per state (states.shuffled)
    steps: int = 3000
    batch: int = 16
    lr: float = 1e-3
    warmup: int = 100
    weight_decay: float = 0.01
    eval_every: int = 250
    heldout_every: int = 10  # every n-th case (by hash) is held out
    seed: int = 0
    threads: int | None = None
    #: Where the updates and the evaluations run: auto (a GPU when torch sees one), cpu, cuda,
    #: cuda:<index>. Checkpoints and the saved model are on the CPU, so a model trained on a GPU
    #: plays and resumes anywhere. Only the CPU promises the same model for the same seed; a
    #: GPU's kernels may differ in the last bits.
    device: str = "cpu"
    #: fp32, or bf16 autocast of the forward passes on a GPU (weights and optimizer float32).
    dtype: AutocastDType = "fp32"
    minutes: float | None = None  # stop early (with a checkpoint) after this long
    #: Stop (with a checkpoint) once this many updates are done, counted like ``steps`` (which
    #: alone sets the schedule): a rerun with a larger ``stop_after`` or none goes on exactly.
    stop_after: int | None = None
    meta: dict[str, Any] = field(default_factory=dict)  # recorded in the model card

    def __post_init__(self) -> None:
        require_choice(self.answer, Answer, "answer")
        check_model_view(
            self.map,
            self.line_fields,
            self.image_tokens,
            self.footprint_pool,
            self.footprint_context,
        )
        check_device("PointerTrainConfig", self.device)
        check_dtype("PointerTrainConfig", self.dtype, self.device)


#: Observations on which a trained model's ONNX export is checked against torch.
TRAIN_CHECK_STATES = 16


def is_heldout(case_id: str, every: int) -> bool:
    return zlib.crc32(case_id.encode()) % every == 0


def load_encoded(
    cfg: PointerTrainConfig, tokenizer: Any, grid: ImageGrid = QWEN3_GRID
) -> tuple[list[Encoded], list[Encoded]]:
    """The labelled states encoded, split into (training, held-out)."""
    train: list[Encoded] = []
    held: list[Encoded] = []
    settings = settings_of(cfg)
    grid, extras = settings_grid(grid, settings), Extras.of(settings)
    for path in cfg.states:
        for s in read_states(Path(path)):
            if s.label < 0:
                continue
            s = shuffled(s, cfg.seed) if cfg.shuffle else s
            e = encode(tokenizer, s, cfg.instructions, cfg.blank_map, cfg.answer, cfg.map, grid,
                       extras=extras)  # fmt: skip
            (held if is_heldout(s.case_id, cfg.heldout_every) else train).append(e)
    if not train:
        raise ValueError(f"{', '.join(cfg.states)}: no labelled training states")
    return train, held


def settings_of(cfg: PointerTrainConfig) -> PromptSettings:
    """The prompt settings the model is trained with (what its card will record)."""
    return PromptSettings(cfg.instructions, cfg.blank_map, cfg.answer, cfg.map, cfg.line_vectors,
                          cfg.line_fields, cfg.image_tokens, cfg.footprint_pool,
                          cfg.footprint_context)  # fmt: skip


#: The card fields a pointer directory continued in training must share with the config.
_KEPT = ("map", "line_fields", "image_tokens")


def _check_continued(cfg: PointerTrainConfig, model: PointerModel) -> None:
    settings = PromptSettings.of(model.vlm.meta)
    for name in _KEPT:
        if getattr(settings, name) != getattr(cfg, name):
            raise ConfigError(
                f"model = {cfg.model!r} was trained with {name} = "
                f"{getattr(settings, name)!r}, not {getattr(cfg, name)!r}"
            )
    for name, have in (
        ("line_vectors", model.lines),
        ("footprint_pool", model.footprint),
        ("footprint_context", model.context),
    ):
        if have != getattr(cfg, name):
            raise ConfigError(
                f"model = {cfg.model!r} was trained with {name} = {have}, not {getattr(cfg, name)}"
            )


def _model(cfg: PointerTrainConfig) -> PointerModel:
    """A pointer directory continues (DAgger rounds); a tiny spec or a plain Qwen-VL checkpoint
    directory gets a fresh pointer head (seeded)."""
    torch.manual_seed(cfg.seed)
    if is_pointer_dir(cfg.model):
        model = load_pointer(cfg.model)
        _check_continued(cfg, model)
        return model.train()
    if not cfg.model.startswith("tiny:") and not Path(cfg.model).is_dir():
        raise ConfigError(f"model = {cfg.model!r}: expected tiny:<family>:<size> or a directory")
    vlm = make_model(cfg.model, seed=cfg.seed)
    return PointerModel(
        vlm, cfg.pool, cfg.map, cfg.line_vectors, cfg.footprint_pool, cfg.footprint_context
    ).train()


def _schedule(cfg: PointerTrainConfig):
    def factor(step: int) -> float:
        if step < cfg.warmup:
            return (step + 1) / cfg.warmup
        done = (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup)
        return 0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(1.0, done)))

    return factor


def _batch(train: Sequence[Encoded], cfg: PointerTrainConfig, step: int, pad: int) -> dict:
    rng = np.random.default_rng([cfg.seed, step])
    picks = rng.choice(len(train), size=min(cfg.batch, len(train)), replace=False)
    return to_device(collate([train[i] for i in picks], pad), cfg.device)


@dataclass
class _State:
    model: PointerModel
    opt: torch.optim.Optimizer
    sched: torch.optim.lr_scheduler.LambdaLR
    step: int = 0
    seconds: float = 0.0


def _setup(cfg: PointerTrainConfig) -> _State:
    model = _model(cfg).to(cfg.device)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, _schedule(cfg))
    st = _State(model, opt, sched)
    ckpt = Path(cfg.out) / CHECKPOINT
    if ckpt.is_file():
        saved = torch.load(ckpt, weights_only=False, map_location="cpu")
        model.load_state_dict(saved["model"])
        opt.load_state_dict(saved["opt"])
        sched.load_state_dict(saved["sched"])
        st.step, st.seconds = saved["step"], saved["seconds"]
    return st


def _on_cpu(value: Any) -> Any:
    """Every tensor in a (nested) state dict moved to the CPU, so that a checkpoint written on
    a GPU loads on a machine without one."""
    if isinstance(value, torch.Tensor):
        return value.cpu()
    if isinstance(value, dict):
        return {k: _on_cpu(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_on_cpu(v) for v in value)
    return value


def _save(cfg: PointerTrainConfig, st: _State) -> None:
    ckpt = Path(cfg.out) / CHECKPOINT
    tmp = ckpt.with_suffix(".tmp")
    torch.save(
        {
            "model": _on_cpu(st.model.state_dict()),
            # Optimizer.load_state_dict moves the moments back to each parameter's device.
            "opt": _on_cpu(st.opt.state_dict()),
            "sched": st.sched.state_dict(),
            "step": st.step,
            "seconds": st.seconds,
        },
        tmp,
    )
    tmp.replace(ckpt)  # atomic: a crash leaves the previous checkpoint whole


def _loss(model: PointerModel, batch: dict, answer: str) -> torch.Tensor:
    """Pointer: cross-entropy over the listed lines against the teacher's soft targets where a
    state has them, else its label. Free JSON: mean NLL of the answer tokens."""
    if answer == "json":
        nll, _ = model.answer_nll(batch)
        return nll.sum() / (batch["answer"][:, 1:] >= 0).sum()
    return soft_loss(model.score(batch), batch["targets"], batch["valid"])


def _update(cfg: PointerTrainConfig, st: _State, batch: dict) -> float:
    with autocast(cfg.device, cfg.dtype):  # the forward pass only; backward follows its dtypes
        loss = _loss(st.model, batch, cfg.answer)
    st.opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(st.model.parameters(), 1.0)
    st.opt.step()
    st.sched.step()
    return loss.item()


#: Called with (log.csv, curves.png) after each evaluation (the CLI draws the curves there).
OnLog = Callable[[Path, Path], None]


def _evaluate(
    cfg, st: _State, held: Heldout, cases: Sequence[Case], loss: float, on_log: OnLog | None
) -> None:
    st.model.eval()  # on the training device: the batches follow the model (pointer.to_device)
    row = {"step": st.step, "seconds": round(st.seconds, 1), "train_loss": round(loss, 4)}
    with autocast(cfg.device, cfg.dtype):
        row.update(heldout_metrics(st.model, held, cfg.answer))
        row.update(closed_loop(st.model, cases, _card(cfg)))
    st.model.train()
    log = Path(cfg.out) / LOG
    new = not log.is_file()
    with open(log, "a") as f:
        if new:
            f.write(",".join(row) + "\n")
        f.write(",".join(str(v) for v in row.values()) + "\n")
    if on_log is not None:
        on_log(log, Path(cfg.out) / "curves.png")


#: The config fields that are paths: recorded as card paths (packlab.policies.provenance), not as
#: given (a scratch ``runs/...`` or absolute path would name one machine's files).
_PATH_FIELDS = ("out", "states", "model")


def _portable_config(cfg: PointerTrainConfig) -> dict[str, Any]:
    kept = {k: v for k, v in asdict(cfg).items() if k not in ("meta", *_PATH_FIELDS)}
    model = cfg.model if cfg.model.startswith("tiny:") else card_path(cfg.model, cfg.out)
    return {**kept, "model": model, "states": [card_path(p, cfg.out) for p in cfg.states]}


def _provenance(cfg: PointerTrainConfig, eval_cases: Sequence[Case]) -> dict[str, Any]:
    init = None if cfg.model.startswith("tiny:") else cfg.model
    rule = (
        "none: the model after the last update is kept; these cases are only monitored "
        "(closed-loop Overall in log.csv)"
    )
    return provenance(
        cfg.out,
        cfg.seed,
        init=init,
        states=cfg.states,
        selection=selection_record(eval_cases, rule),
    )


def _card(cfg: PointerTrainConfig) -> dict[str, Any]:
    return {
        "proposer": asdict(ProposerConfig(k=cfg.k)),
        "line_vectors": cfg.line_vectors,
        "line_fields": cfg.line_fields,
        "image_tokens": cfg.image_tokens,
        "footprint_pool": cfg.footprint_pool,
        "footprint_context": cfg.footprint_context,
        "instructions": cfg.instructions,
        "blank_map": cfg.blank_map,
        "map": cfg.map,
        "pool": cfg.pool,
        "answer": cfg.answer,
        "shuffle": cfg.shuffle,
        "pointer_train": _portable_config(cfg),
        **cfg.meta,
    }


def train_pointer(
    cfg: PointerTrainConfig, eval_cases: Sequence[Case] = (), on_log: OnLog | None = None
) -> Path:
    """Train (or resume) and write ``out/final`` with its ONNX export (index answers; the
    free-JSON ablation and footprint pooling play under torch only); returns that directory."""
    torch.set_num_threads(cfg.threads) if cfg.threads else None
    # "auto" resolved once (the card records the device used); refused here before any work.
    cfg = replace(cfg, device=placement("PointerTrainConfig", cfg.device, cfg.dtype))
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    st = _setup(cfg)
    train, held_list = load_encoded(cfg, st.model.vlm.tokenizer, ImageGrid.of(st.model.vlm))
    held = Heldout.of(held_list, train)
    pad = st.model.vlm.tokenizer.pad_token_id
    bar = tqdm(total=cfg.steps, initial=st.step, desc="train pointer", unit="step")
    losses: list[float] = []
    start = time.perf_counter() - st.seconds
    end = cfg.steps if cfg.stop_after is None else min(cfg.steps, cfg.stop_after)
    while st.step < end:
        losses.append(_update(cfg, st, _batch(train, cfg, st.step, pad)))
        st.step += 1
        st.seconds = time.perf_counter() - start
        bar.update(1)
        over = cfg.minutes is not None and st.seconds > 60 * cfg.minutes
        if st.step % cfg.eval_every == 0 or st.step == end or over:
            loss = float(np.mean(losses[-cfg.eval_every :]))
            _evaluate(cfg, st, held, eval_cases, loss, on_log)
            _save(cfg, st)
        if over:
            break
    bar.close()
    st.model.eval().cpu()
    card = {**_card(cfg), "trained_steps": st.step, "train_seconds": round(st.seconds, 1),
            "train_states": len(train), "heldout_states": len(held_list),
            **_provenance(cfg, eval_cases)}  # fmt: skip
    final = save_pointer(st.model, out / "final", card)
    if cfg.answer == "index" and not cfg.footprint_pool:  # plays under the default runtime
        export_onnx(final, check_states=TRAIN_CHECK_STATES)
    return final
