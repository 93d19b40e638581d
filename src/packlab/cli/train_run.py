"""What ``packlab train sft`` and ``train candidate`` do (:mod:`packlab.cli.train` defines their
flags and imports this module when one runs): the training-data guard, the trainers of the vlm
extra (reached through ``packlab.cli.train._torch_side``), the curves."""

from __future__ import annotations

import argparse
from pathlib import Path

from packlab.bench.suites import resolve_cases
from packlab.cli import train as train_cli
from packlab.cli.options import config_kwargs
from packlab.datagen.format import INFO_FILE
from packlab.datagen.guard import require_training_cases
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


def run_sft(args: argparse.Namespace) -> int:
    cfg = train_cli.config_from_args(args)
    check_sft_data(cfg.data)
    trainer = train_cli._torch_side(TRAINER_MODULE)
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
