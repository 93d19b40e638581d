"""The candidate-mode recipe: teacher rollouts, then DAgger rounds, each followed by training.

Round 0 plays its cases with the teacher and trains a fresh model on those states. Round r >= 1
plays new cases with round r-1's model (the student acts: beta = 0), labels every state it
reaches with the teacher, and continues training round r-1's model on all states so far. Each
round's cases are new generated cases, split evenly over the levels; a few cases per level are
kept out of every round for the closed-loop evaluation during training. Every stage resumes:
collection skips cases already in its file, training resumes from its checkpoint, and a round
whose model is written is skipped. Training and its evaluations run on ``device`` at ``dtype``
(:mod:`.device`); collection plays the previous round's ONNX export on the CPU (one decision at
a time in worker processes, where a GPU would gain little and CUDA does not survive a fork).
Imports torch: only the vlm extra may import this module.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

from packlab.core.types import Case
from packlab.policies.candidates import ProposerConfig
from packlab.vlm.candidate.collect import collect
from packlab.vlm.candidate.dagger_split import split_cases
from packlab.vlm.candidate.device import placement
from packlab.vlm.candidate.recipe import DaggerConfig
from packlab.vlm.candidate.states import STATES_FILE
from packlab.vlm.candidate.states_guard import require_training_states
from packlab.vlm.candidate.train import OnLog, PointerTrainConfig, train_pointer


def _round_config(
    cfg: DaggerConfig, r: int, named: dict[str, str] | None = None, device: str = "cpu"
) -> PointerTrainConfig:
    """Round ``r``'s training, on ``device`` (``cfg.device`` resolved: :func:`run_dagger`)."""
    out = Path(cfg.out)
    return PointerTrainConfig(
        states=tuple(str(out / f"r{k}" / STATES_FILE) for k in range(r + 1)),
        out=str(out / f"r{r}" / "train"),
        model=cfg.model if r == 0 else str(out / f"r{r - 1}" / "train" / "final"),
        instructions=cfg.instructions,
        blank_map=cfg.blank_map,
        map=cfg.map,
        line_vectors=cfg.line_vectors,
        line_fields=cfg.line_fields,
        image_tokens=cfg.image_tokens,
        footprint_pool=cfg.footprint_pool,
        footprint_context=cfg.footprint_context,
        k=cfg.k,
        shuffle=cfg.shuffle,
        pool=cfg.pool,
        steps=cfg.steps if r == 0 else cfg.round_steps,
        batch=cfg.batch,
        lr=cfg.lr,
        seed=cfg.seed + r,
        minutes=cfg.minutes_per_round,
        threads=cfg.threads,
        device=device,
        dtype=cfg.dtype,
        meta={
            "teacher": cfg.teacher,
            "dagger_round": r,
            "dagger_rounds": cfg.rounds,
            "cases": named or {},  # the training cases by name and digest, for the card
        },
    )


def run_dagger(
    cfg: DaggerConfig,
    cases: Sequence[Case],
    on_log: OnLog | None = None,
    named: dict[str, str] | None = None,
) -> Path:
    """Run (or resume) every round; the final model is copied to ``out/final``. ``named``:
    the cases' ``source`` and ``sha256`` as the card records them (``cases_record``)."""
    # Refuse a device that is not here (or bf16 where it does not run) before any collection.
    device = placement("DaggerConfig", cfg.device, cfg.dtype)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "dagger.json").write_text(json.dumps(asdict(cfg), indent=1) + "\n")
    rounds, evals = split_cases(cases, cfg.cases_per_round, cfg.rounds, cfg.eval_cases_per_level)
    final = None
    for r, round_cases in enumerate(rounds):
        train_cfg = _round_config(cfg, r, named, device)
        actor = None if r == 0 else ("vlm", {"model": train_cfg.model, "threads": 1})
        source = "teacher" if r == 0 else f"student-r{r}"
        collect(round_cases, out / f"r{r}" / STATES_FILE, cfg.teacher, source, actor,
                ProposerConfig(k=cfg.k), workers=cfg.workers)  # fmt: skip
        # Collection adds only the cases missing from a file (by id): check every row by content.
        require_training_states(train_cfg.states, cases)
        final = Path(train_cfg.out) / "final"
        if not (final / "pointer_head.safetensors").is_file():
            final = train_pointer(train_cfg, evals, on_log)
    assert final is not None
    shutil.copytree(final, out / "final", dirs_exist_ok=True)
    return out / "final"
