"""What ``packlab train sft`` and ``train candidate`` do (:mod:`packlab.cli.train` defines their
flags and imports this module when one runs): the training-data guard, the trainers of the vlm
extra (reached through ``packlab.cli.train._torch_side``), the curves."""

from __future__ import annotations

import argparse
from pathlib import Path

from packlab.bench.suites import resolve_cases
from packlab.cli import train as train_cli
from packlab.cli.options import config_kwargs
from packlab.core.types import Case
from packlab.datagen.config import DIFFICULTIES, CaseConfig
from packlab.datagen.format import INFO_FILE
from packlab.datagen.generator import slot_case
from packlab.datagen.guard import require_training_cases
from packlab.datagen.seeds import id_prefix
from packlab.datagen.stats import dataset_cases
from packlab.policies.provenance import cases_record
from packlab.viz.plots import plot_loss_curve
from packlab.viz.pointer_curves import write_curves
from packlab.vlm.candidate.recipe import DAGGER_MODULE, DaggerConfig
from packlab.vlm.candidate.states import STATES_FILE
from packlab.vlm.candidate.states_guard import require_training_states

#: The trainer's module (vlm extra), imported when the command runs.
TRAINER_MODULE = "packlab.vlm.train.sft"


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


def play_cases(per_level: int, user_seed: int) -> list[Case]:
    """The generated validation cases a model plays during SFT: ``per_level`` of each level,
    in the training seed domain under their own user seed (checked against the bench)."""
    prefix = id_prefix("train", user_seed) + "play-"
    cases = [
        slot_case(user_seed, "train", d, slot, 0, CaseConfig(), prefix)
        for d in DIFFICULTIES
        for slot in range(per_level)
    ]
    return list(require_training_cases(cases, f"play cases (seed {user_seed})"))


def run_sft(args: argparse.Namespace) -> int:
    cfg = train_cli.config_from_args(args)
    check_sft_data(cfg.data)
    trainer = train_cli._torch_side(TRAINER_MODULE)
    cases = play_cases(cfg.play_cases, cfg.play_seed) if cfg.play_cases else None
    res = trainer.train_sft(cfg, play_cases=cases)
    if not res.is_main_process:
        return 0  # under accelerate/torchrun only rank 0 reports
    if res.losses:
        title = f"SFT {cfg.model} ({res.n_examples} conversations)"
        plot_loss_curve(res.loss_log, res.out / "loss_curve.png", title=title)
    resumed = f" (resumed from {res.resumed_from})" if res.resumed_from else ""
    dropped = f", {res.dropped_examples} dropped for length" if res.dropped_examples else ""
    loss = f"loss {res.losses[0]:.4f} -> {res.losses[-1]:.4f}; " if res.losses else ""
    print(
        f"trained {res.optimizer_steps} steps{resumed} on {res.n_examples} conversations "
        f"({res.labelled_actions} labelled actions{dropped}) in {res.wall_time_s:.0f} s; "
        f"{loss}final model: {res.final_checkpoint}"
    )
    return 0


def run_candidate(args: argparse.Namespace) -> int:
    cfg = DaggerConfig(**config_kwargs(args, "train candidate", DaggerConfig))
    source = resolve_cases(args.cases)
    cases = require_training_cases(source.cases, source.origin)
    # A resumed run reuses the states already in its rounds' files (collection skips their
    # case ids): refuse them now, before any work, if they are not of these cases.
    require_training_states(sorted(Path(cfg.out).glob(f"r*/{STATES_FILE}")), cases)
    dagger = train_cli._torch_side(DAGGER_MODULE)
    named = cases_record(source.origin, source.sha256, cfg.out)
    final = dagger.run_dagger(cfg, cases, write_curves, named)
    print(f"final model: {final} (log and curves under {cfg.out}/r*/train)")
    return 0
