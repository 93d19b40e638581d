"""``packlab train rl``: train an RL baseline (irbpp or tapnet) with MaskablePPO (rl extra)."""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path
from typing import Any

from packlab.bench.suites import resolve_cases
from packlab.cases import cases_sha256
from packlab.cli.options import add_field, config_kwargs
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
from packlab.vlm.candidate.states import listed_of, observation_of, read_states

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


def register_rl(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser(
        "rl",
        help="train an RL baseline: irbpp (pick a listed placement) or tapnet (pick the object)",
        description="MaskablePPO (sb3-contrib) on the geometric backend, one agent over all "
        "levels; held-out evaluation, checkpoints, log.csv and curves.png under --out. "
        "Rerun the same command to resume.",
    )
    field = partial(add_field, r, RLTrainConfig)
    field("agent", "--agent", help="default {default}")
    r.add_argument(
        "--cases",
        default="packdata-20k",
        help="a dataset recipe (generated now) or generated cases on disk; default %(default)s",
    )
    field("steps", "--steps", help="env steps in total; default {default}")
    field("out", "--out", help="run directory; default {default}")
    field("minutes", "--minutes", help="wall-time cap across resumes (0: none)")
    field("envs", "--envs", help="environment copies; default {default}")
    field("vec", "--vec", help="default {default}")
    field("reward", "--reward", help="default {default}")
    field("k", "--k", help="irbpp: placements listed per step; default {default}")
    field("n_steps", "--n-steps", help="steps per env per rollout; default {default}")
    field("batch", "--batch", help="default {default}")
    field("epochs", "--epochs", help="default {default}")
    field("lr", "--lr", help="default {default}")
    field("gamma", "--gamma", help="default {default}")
    field("ent_coef", "--ent-coef", help="default {default}")
    field("width", "--width", help="default {default}")
    field("eval_every", "--eval-every", help="env steps; default {default}")
    field("eval_cases_per_level", "--eval-cases", help="held out per level; default {default}")
    field("seed", "--seed", help="default {default}")
    field("threads", "--threads", help="torch threads of the learner; default {default}")
    field("init", "--init", help="a model directory to start from (e.g. rl-imitate's --out)")
    r.set_defaults(func=run_rl)
    register_rl_imitate(sub)


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

    The states keep no case seeds, so the training-data guard runs on their cases as follows:
    with ``cases`` (the cases the states were collected on) every state's case must be one of
    them and they pass :func:`require_training_cases`; without, every case id must carry the
    training domain's id prefix (``train-``), which bench suites never do.
    """
    known = {c.episode_id for c in cases} if cases is not None else None
    demos = []
    for state in read_states(path):
        if known is not None and state.case_id not in known:
            raise ConfigError(f"{path}: case {state.case_id!r} is not among --cases")
        if known is None and not state.case_id.startswith(TRAIN_ID_PREFIX):
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


def register_rl_imitate(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser(
        "rl-imitate",
        help="behaviour-clone an RL agent (irbpp or tapnet) from planner-labelled states",
        description="Fit the agent's actor to a teacher's picks in candidate-mode states "
        "(JSONL, packlab.vlm.candidate.states) and save a model directory that packlab bench "
        "plays (--policy-arg irbpp:model=DIR) and packlab train rl --init DIR continues.",
    )
    field = partial(add_field, r, ImitationConfig)
    field("agent", "--agent", help="default {default}")
    r.add_argument("--states", required=True, help="labelled states (JSONL)")
    r.add_argument(
        "--cases",
        default=None,
        help="the generated cases the states come from (recipe or path), checked by their "
        "seeds; without it, the states' case ids must be training-domain ids (train-...)",
    )
    field("out", "--out", help="model directory; default {default}")
    for name in ("k", "width", "epochs", "batch", "lr", "value_weight", "seed", "threads"):
        field(name, "--" + name.replace("_", "-"), help="default {default}")
    r.set_defaults(func=run_rl_imitate)


def run_rl_imitate(args: argparse.Namespace) -> int:
    try:
        fit = import_rl(IMITATION_MODULE)
    except RLExtraMissing as e:
        raise PacklabError(str(e)) from None
    cfg = ImitationConfig(**config_kwargs(args, "train rl-imitate", ImitationConfig))
    cases = training_cases(args.cases)[0] if args.cases else None
    demos = demos_from_states(Path(args.states), cases)
    samples = imitation_samples(demos, FeatureSpec.default(cfg.agent, cfg.k))
    res = fit.imitate(samples, cfg, str(args.states))
    print(
        f"{cfg.agent}: {res.n_samples:,} samples from {len(demos):,} states, {cfg.epochs} epochs "
        f"in {res.wall_time_s:.0f} s; loss {res.losses[0]:.3f} -> {res.losses[-1]:.3f}, "
        f"teacher's row ranked first {res.accuracy:.1%}; model {res.out}"
    )
    return 0
