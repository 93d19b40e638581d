"""What ``packlab train rl`` and ``train rl-imitate`` do: train an RL baseline (irbpp or tapnet)
with MaskablePPO, or behaviour-clone one (rl extra). :mod:`packlab.cli.train` defines their flags
and imports this module when one runs."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from packlab.bench.suites import resolve_cases
from packlab.cases import cases_sha256
from packlab.cli.options import config_kwargs
from packlab.core.errors import ConfigError, PacklabError
from packlab.core.types import Action, Case
from packlab.datagen.config import RECIPES
from packlab.datagen.generator import generate_cases
from packlab.datagen.guard import require_training_cases
from packlab.rl.config import ImitationConfig, RLTrainConfig
from packlab.rl.extra import RLExtraMissing, import_rl
from packlab.rl.features import FeatureSpec
from packlab.rl.imitation import Demo, imitation_samples
from packlab.viz.rl_curves import write_rl_curves
from packlab.vlm.candidate.states import listed_of, observation_of
from packlab.vlm.candidate.states_guard import checked_states

TRAINER_MODULE = "packlab.rl.train"


def training_cases(spec: str) -> tuple[list[Case], dict[str, Any]]:
    """The cases ``--cases`` names and their source record.

    A dataset recipe name (``packdata-20k``, ``packdata-mini``) generates its cases in the
    training seed domain without the physics replay (agents train on the geometric backend);
    a path loads a case file or ``packlab generate`` output. Cases from the bench seed domain
    are refused by their seeds (``packlab.datagen.guard``), however they are named: a suite, or
    the same suite exported to a file.
    """
    if spec in RECIPES:
        recipe = RECIPES[spec]
        print(f"generating {sum(recipe.episodes):,} training cases ({spec}) ...", flush=True)
        cases = [
            case
            for level, n in zip(recipe.difficulties, recipe.episodes)
            for case in generate_cases(level, n, recipe.seed, validate=False, domain="train")
        ]
        cases = require_training_cases(cases, f"recipe:{spec}")
        return cases, {"cases": f"recipe:{spec}", "cases_sha256": cases_sha256(cases)}
    source = resolve_cases(spec)
    cases = require_training_cases(source.cases, source.origin)
    return cases, {"cases": source.origin, "cases_sha256": source.sha256}


def run_rl(args: argparse.Namespace) -> int:
    cfg = RLTrainConfig(**config_kwargs(args, "train rl", RLTrainConfig))
    try:
        trainer = import_rl(TRAINER_MODULE)
    except RLExtraMissing as e:
        raise PacklabError(str(e)) from None
    cases, source = training_cases(args.cases)
    res = trainer.train_rl(cfg, cases, source, write_rl_curves)
    print(
        f"{cfg.agent}: {res.env_steps:,} env steps in {res.wall_time_s / 60:.1f} min; "
        f"held-out Overall best {res.best.get('avg', float('nan')):.3f} (model {res.out}/best), "
        f"final {res.final.get('avg', float('nan')):.3f} (model {res.out}/final)"
    )
    return 0


IMITATION_MODULE = "packlab.rl.imitation_fit"
#: The id prefix ``generate_cases(..., domain="train")`` gives its cases (``id_prefix`` default).
TRAIN_ID_PREFIX = "train-"


def demos_from_states(path: Path, cases: list[Case] | None = None) -> list[Any]:
    """Candidate-mode labelled states (``packlab.vlm.candidate.states``) as imitation demos:
    the teacher's pick ``listed[label]`` and, where the file has one, ``soft`` over listed.

    Every row is checked by its case's content fingerprint
    (:func:`packlab.vlm.candidate.states_guard.checked_states`): a row of a suite case is
    refused, and with ``cases`` (the cases the states were collected on, which pass
    :func:`require_training_cases`) a row whose case is not among them or is another case
    under the same id is refused. Without ``cases`` every case id must also carry the training
    domain's id prefix (``train-``), which bench suites never do.
    """
    demos = []
    for state in checked_states(path, cases):
        if cases is None and not state.case_id.startswith(TRAIN_ID_PREFIX):
            raise ConfigError(
                f"{path}: case {state.case_id!r} is not a training-domain id; pass --cases with "
                "the generated cases the states were collected on"
            )
        if state.label < 0:
            continue
        actions = [Action(c.object_index, c.rotation, c.x, c.y) for c in listed_of(state)]
        soft = tuple(zip(actions, getattr(state, "soft", ()) or ()))
        demos.append(Demo(observation_of(state), actions[state.label], soft))
    return demos


def run_rl_imitate(args: argparse.Namespace) -> int:
    try:
        fit = import_rl(IMITATION_MODULE)
    except RLExtraMissing as e:
        raise PacklabError(str(e)) from None
    cfg = ImitationConfig(**config_kwargs(args, "train rl-imitate", ImitationConfig))
    cases, source = training_cases(args.cases) if args.cases else (None, {})
    demos = demos_from_states(Path(args.states), cases)
    samples = imitation_samples(demos, FeatureSpec.default(cfg.agent, cfg.k, cfg.placement))
    named = (source.get("cases", ""), source.get("cases_sha256", ""))
    res = fit.imitate(samples, cfg, str(args.states), named)
    print(
        f"{cfg.agent}: {res.n_samples:,} samples from {len(demos):,} states, {cfg.epochs} epochs "
        f"in {res.wall_time_s:.0f} s; loss {res.losses[0]:.3f} -> {res.losses[-1]:.3f}, "
        f"teacher's row ranked first {res.accuracy:.1%}; model {res.out}"
    )
    return 0
