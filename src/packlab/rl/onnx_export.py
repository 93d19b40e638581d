"""``packlab export onnx DIR`` for an RL agent directory (rl extra: torch, sb3-contrib).

:func:`export_onnx` writes the agent's greedy path (:class:`packlab.rl.networks.ActorLogits`,
the function the torch runtime calls) as ``policy.onnx`` with torch's dynamo exporter (fixed
shapes: one observation per call, as the bench plays), checks on observations of a few
episodes that ONNX Runtime then picks the same row as torch under the shared decision rule
(:func:`packlab.rl.decision.pick_row`), and only then writes ``onnx.json``
(:mod:`packlab.policies.onnx_model`). A check that fails leaves the directory as it was.
"""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from packlab.cases import load_cases
from packlab.core.errors import ConfigError
from packlab.policies.onnx_model import GraphSpec, OnnxCard, file_sha256, new_session, write_card
from packlab.policies.random_policy import RandomPolicy
from packlab.rl.agent import load_agent, row_logits
from packlab.rl.card import CARD_FILE, MODEL_FILE
from packlab.rl.decision import SET_ASIDE, pick_row
from packlab.rl.features import GRID, N_GLOBALS, N_ITEM_FEATURES, Encoded, FeatureSpec, encode
from packlab.rl.networks import ActorLogits
from packlab.rl.onnx_agent import GRAPH, GRAPH_FILE, INPUTS, ONNX_KIND, OUTPUTS, batched
from packlab.sim.env import demo_cases_path
from packlab.sim.episode import Episode, policy_start

#: The ONNX opset the graphs are written with (recorded in onnx.json); 18 is the dynamo
#: exporter's own and ONNX Runtime >= 1.14 runs it.
OPSET = 18
#: Check states come from seeded random play of the bundled demo cases, episode after episode.
CHECK_SEED = 0


@dataclass(frozen=True, slots=True)
class CheckReport:
    """How the ONNX graph compared with torch on the check states."""

    states: int
    disagreements: int
    first: int | None  # index of the first disagreeing state
    max_abs_logit_diff: float


def collect_check_states(spec: FeatureSpec, count: int, seed: int = CHECK_SEED) -> list[Encoded]:
    """``count`` encoded observations that list something, from seeded random play of the demo
    cases (geometric backend): states of many fill levels, not only the agent's own."""
    cases = load_cases(demo_cases_path())
    policy, episode = RandomPolicy(), Episode("geometric")
    states: list[Encoded] = []
    run = 0
    while len(states) < count:
        case = cases[run % len(cases)]
        observation = episode.reset(case, seed + run)
        policy.reset(policy_start(policy, case, seed + run), seed + run)
        while not episode.done and len(states) < count:
            encoded = encode(observation, spec)
            if encoded.actions:
                states.append(encoded)
            episode.step(policy.act(observation) if encoded.actions else SET_ASIDE)
            if not episode.done:
                observation = episode.observe()
        run += 1
    return states


@contextlib.contextmanager
def _quiet_exporter() -> Iterator[None]:
    """The dynamo exporter logs a warning per missing torchvision op and torch.export warns of
    its own deprecations; neither is the user's to act on."""
    logger = logging.getLogger("torch.onnx")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            yield
    finally:
        logger.setLevel(level)


def write_graph(module: ActorLogits, spec: FeatureSpec, path: Path) -> None:
    """``module`` as an ONNX graph at ``path``: one observation in, (1, N) logits out."""
    example = (
        torch.zeros(1, 1, GRID, GRID),
        torch.zeros(1, N_GLOBALS),
        torch.zeros(1, spec.n_items, N_ITEM_FEATURES),
    )
    with _quiet_exporter(), torch.no_grad():
        torch.onnx.export(
            module,
            example,
            str(path),
            input_names=list(INPUTS),
            output_names=list(OUTPUTS),
            opset_version=OPSET,
            dynamo=True,
            external_data=False,  # one self-contained file (the weights are ~250 kB)
            verbose=False,
        )


def compare(model: object, graph_path: Path, states: list[Encoded]) -> CheckReport:
    """Torch's and ONNX Runtime's greedy rows on ``states`` (the shared rule on each's logits)."""
    session = new_session(graph_path, threads=1)
    disagreements, first, worst = 0, None, 0.0
    for i, encoded in enumerate(states):
        torch_logits = row_logits(model, encoded.arrays)
        onnx_logits = session.run(list(OUTPUTS), batched(encoded.arrays))[0][0]
        real = encoded.mask
        worst = max(worst, float(np.abs(torch_logits[real] - onnx_logits[real]).max()))
        if pick_row(torch_logits, real) != pick_row(onnx_logits, real):
            disagreements += 1
            first = i if first is None else first
    return CheckReport(len(states), disagreements, first, worst)


def export_onnx(directory: Path, check_states: int = 64) -> OnnxCard:
    """Export the agent of ``directory`` (module docstring); its ``onnx.json`` card."""
    directory = Path(directory)
    loaded = load_agent(directory)
    spec = loaded.card.spec
    partial = directory / f".{GRAPH_FILE}.partial"
    try:
        write_graph(ActorLogits(loaded.model.policy), spec, partial)
        states = collect_check_states(spec, check_states) if check_states > 0 else []
        report = compare(loaded.model, partial, states)
        if report.disagreements:
            raise ConfigError(
                f"{directory}: ONNX Runtime picks another row than torch on "
                f"{report.disagreements} of {report.states} check states (first: state "
                f"{report.first}; max |logit difference| {report.max_abs_logit_diff:.2e}); "
                "nothing was written"
            )
        os.replace(partial, directory / GRAPH_FILE)
    finally:
        partial.unlink(missing_ok=True)
    card = OnnxCard(
        kind=ONNX_KIND,
        graphs={GRAPH: GraphSpec(GRAPH_FILE, INPUTS, OUTPUTS)},
        sources={name: file_sha256(directory / name) for name in (MODEL_FILE, CARD_FILE)},
        opset=OPSET,
        exported_with=f"torch {torch.__version__}",
        extra={
            "agent": loaded.card.agent,
            "n_items": loaded.card.n_items,
            "features": loaded.card.features,
            "exporter": "torch.onnx.export(dynamo=True)",
            "check_states": report.states,
            "max_abs_logit_diff": report.max_abs_logit_diff,
        },
    )
    write_card(directory, card)
    return card
