"""``packlab export onnx DIR`` for a candidate-mode pointer model: its ONNX graphs and card.

Writes ``vision.onnx`` (models that see an image) and ``text.onnx`` (:mod:`.onnx_graphs`) into
the checkpoint directory, then plays both runtimes on generated observations (random listed
picks on the bundled demo cases, geometric backend) and requires ONNX Runtime
(:mod:`.onnx_scoring`, the very code the policy runs) to pick the same listed placement as torch
(:mod:`.scoring`) before it writes ``onnx.json`` (:mod:`packlab.policies.onnx_model`). A pick
that differs only between two placements whose torch scores tie within
:data:`TIE_TOLERANCE` is not an error (float rounding may order a tie either way).

The TorchScript exporter (``torch.onnx.export(..., dynamo=False)``) is used: torch.export
(the dynamo exporter) stops at the vision tower's data-dependent attention windows, while
tracing turns the fixed image grid into constants and keeps the sequence length and the number
of listed lines dynamic. Imports torch: only the vlm extra may import this module.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from packlab.cases.load import load_cases
from packlab.core.errors import ConfigError
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Case, Observation
from packlab.policies.candidates import Candidate, ProposerConfig, propose
from packlab.policies.onnx_model import (
    CARD_FILE,
    GraphSpec,
    OnnxCard,
    OnnxGraph,
    file_sha256,
    new_session,
    write_card,
)
from packlab.policies.registry import make_policy
from packlab.sim.env import demo_cases_path
from packlab.sim.episode import run_episode
from packlab.vlm.candidate import onnx_scoring, scoring
from packlab.vlm.candidate.encoding import ImageGrid, PromptSettings
from packlab.vlm.candidate.files import HEAD_FILE
from packlab.vlm.candidate.json_tokenizer import JsonTokenizer
from packlab.vlm.candidate.onnx_graphs import (
    TEXT_OUTPUTS,
    VISION_INPUTS,
    TextGraph,
    VisionGraph,
)
from packlab.vlm.candidate.onnx_scoring import POINTER_KIND, TEXT_GRAPH, VISION_GRAPH, OnnxPointer
from packlab.vlm.candidate.pointer import PointerModel
from packlab.vlm.candidate.saved import load_pointer
from packlab.vlm.model.checkpoint import PACKLAB_META

OPSET = 17
EXPORTER = "torch.onnx.export (TorchScript, dynamo=False)"
#: Torch score gap under which two placements count as tied (either pick agrees).
TIE_TOLERANCE = 1e-4
#: The checkpoint files the graphs are made from (the card's ``sources``).
SOURCES = ("model.safetensors", HEAD_FILE, PACKLAB_META)
#: Dynamic axes of the text graph: the sequence length T and the number of listed lines K.
TEXT_AXES = {
    "input_ids": {1: "T"}, "position_ids": {2: "T"}, "ends": {0: "K"}, "starts": {0: "K"},
    "vectors": {0: "K"}, "scores": {0: "K"},
}  # fmt: skip


@dataclass(frozen=True, slots=True)
class CheckReport:
    """How the ONNX graphs agreed with torch on the check states."""

    states: int
    argmax_equal: int
    ties: int  # picks that differ between placements tied within TIE_TOLERANCE
    max_abs_diff: float


class RandomListed:
    """Plays a random listed placement (SDF-Pack when none is listed), recording each step's
    observation and listed placements: varied states for the check."""

    name = "random-listed"

    def __init__(self, proposer: ProposerConfig, seed: int) -> None:
        self.proposer, self.rng = proposer, np.random.default_rng(seed)
        self.states: list[tuple[Observation, list[Candidate]]] = []

    def reset(self, start: EpisodeStart, seed: int) -> None:
        self.fallback = make_policy("sdf")
        self.fallback.reset(start, seed)

    def act(self, observation: Observation) -> Any:
        listed = list(propose(observation, self.proposer))
        if not listed:
            return self.fallback.act(observation)
        self.states.append((observation, listed))
        return listed[int(self.rng.integers(len(listed)))].action


def check_observations(
    n: int, proposer: ProposerConfig, cases: Sequence[Case] = ()
) -> list[tuple[Observation, list]]:
    """``n`` observations with at least one listed placement, played on ``cases`` (default:
    the bundled demo cases) with a new seed for each episode."""
    cases = list(cases) or load_cases(demo_cases_path())
    states: list[tuple[Observation, list[Candidate]]] = []
    for seed in range(1000):
        player = RandomListed(proposer, seed)
        run_episode(cases[seed % len(cases)], player, seed=seed, backend="geometric")
        states += player.states
        if len(states) >= n:
            return states[:n]
    raise ConfigError(f"the cases gave only {len(states)} check states of {n}")


def _export(module: torch.nn.Module, args: tuple, path: Path, **kw: Any) -> None:
    """``torch.onnx.export`` to a temporary name, then renamed (a reader never sees half a
    file); the tracer's warnings about constants are expected (the image grid is one)."""
    tmp = path.with_suffix(".onnx.tmp")
    with warnings.catch_warnings(), torch.inference_mode(False), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(module.eval(), args, str(tmp), dynamo=False, opset_version=OPSET, **kw)
    os.replace(tmp, path)


def _open(directory: Path, spec: GraphSpec) -> OnnxGraph:
    graph = OnnxGraph(spec, new_session(directory / spec.file, threads=1))
    names = tuple(i.name for i in graph.session.get_inputs())
    if names != spec.inputs:
        raise ConfigError(f"{directory / spec.file}: graph inputs {names}, expected {spec.inputs}")
    return graph


def export_vision(model: PointerModel, grid: ImageGrid, directory: Path) -> GraphSpec:
    graph = VisionGraph(model, grid.thw)
    spec = GraphSpec(f"{VISION_GRAPH}.onnx", VISION_INPUTS, graph.outputs)
    pixels = np.zeros((1, grid.side, grid.side), dtype=np.uint8)
    sample = torch.from_numpy(grid.pixels(pixels)[0])
    _export(graph, (sample,), directory / spec.file,
            input_names=list(spec.inputs), output_names=list(spec.outputs))  # fmt: skip
    return spec


def export_text(
    model: PointerModel, runtime: OnnxPointer, sample: tuple[Observation, list], directory: Path
) -> GraphSpec:
    """The text graph, traced on one state's inputs (T and K stay dynamic)."""
    graph = TextGraph(model, VISION_GRAPH in runtime.graphs)
    spec = GraphSpec(f"{TEXT_GRAPH}.onnx", graph.names, TEXT_OUTPUTS)
    settings = PromptSettings.of(runtime.meta)
    enc = onnx_scoring.encode_step(runtime, *sample, settings)
    feed = onnx_scoring.graph_inputs(runtime, enc)
    args = tuple(torch.from_numpy(np.ascontiguousarray(feed[n])) for n in graph.names)
    axes = {n: a for n, a in TEXT_AXES.items() if n in graph.names or n in TEXT_OUTPUTS}
    _export(graph, args, directory / spec.file, input_names=list(spec.inputs),
            output_names=list(spec.outputs), dynamic_axes=axes)  # fmt: skip
    return spec


def compare(
    model: PointerModel, runtime: OnnxPointer, states: Sequence[tuple[Observation, list]]
) -> CheckReport:
    """Scores of both runtimes on each state; a ConfigError at the first real disagreement."""
    settings = PromptSettings.of(runtime.meta)
    equal = ties = 0
    worst = 0.0
    for n, (observation, listed) in enumerate(states):
        ref = scoring.score_listed(model, observation, listed, settings)
        got = onnx_scoring.score_listed(runtime, observation, listed, settings)
        worst = max(worst, float(np.abs(ref - got).max()))
        a, b = int(np.argmax(ref)), int(np.argmax(got))
        if a == b:
            equal += 1
        elif ref[a] - ref[b] <= TIE_TOLERANCE:
            ties += 1
        else:
            raise ConfigError(
                f"ONNX check failed on state {n} (step {observation.step_index}): torch picks "
                f"listed {a} (score {ref[a]:.6f}), ONNX picks {b} (torch score {ref[b]:.6f}, "
                f"ONNX {got[b]:.6f}); max abs score difference so far {worst:.3g}"
            )
    return CheckReport(len(states), equal, ties, worst)


#: The model families whose pointer models export (their decoder layers take the additive
#: causal mask the text graph builds; Qwen3.5's linear-attention layers do not).
EXPORTABLE_FAMILIES = ("qwen3_vl", "qwen2_5_vl")


def _model(directory: Path) -> tuple[PointerModel, OnnxPointer]:
    model = load_pointer(directory)
    if model.context:
        raise ConfigError(
            f"{directory}: a pointer model with footprint pooling and its context "
            "(footprint_pool = true, footprint_context = true); its head gathers visual tokens "
            "per listed line (under and around its footprint), which the ONNX text graph does "
            "not take: play it with runtime=torch"
        )
    if model.footprint:
        raise ConfigError(
            f"{directory}: a pointer model with footprint pooling (footprint_pool = true); "
            "its head gathers visual tokens per listed line, which the ONNX text graph does not "
            "take: play it with runtime=torch"
        )
    if model.vlm.family not in EXPORTABLE_FAMILIES:
        raise ConfigError(
            f"{directory}: a {model.vlm.family} pointer model; ONNX export supports "
            f"{', '.join(EXPORTABLE_FAMILIES)} (play it with runtime=torch)"
        )
    meta = dict(model.vlm.meta)
    runtime = OnnxPointer(directory, meta, JsonTokenizer(directory), ImageGrid.of(model.vlm), {})
    return model, runtime


def export_onnx(directory: Path, check_states: int = 64) -> OnnxCard:
    """Export the pointer model of ``directory`` (module docstring); the card written."""
    directory = Path(directory)
    model, runtime = _model(directory)
    (directory / CARD_FILE).unlink(missing_ok=True)  # no card names graphs being rewritten
    proposer = ProposerConfig(**runtime.meta["proposer"])
    states = check_observations(max(check_states, 1), proposer)
    specs: dict[str, GraphSpec] = {}
    if VISION_GRAPH in onnx_scoring.graph_names(runtime.meta):
        specs[VISION_GRAPH] = export_vision(model, runtime.grid, directory)
        runtime.graphs[VISION_GRAPH] = _open(directory, specs[VISION_GRAPH])
    specs[TEXT_GRAPH] = export_text(model, runtime, states[0], directory)
    runtime.graphs[TEXT_GRAPH] = _open(directory, specs[TEXT_GRAPH])
    report = compare(model, runtime, states[:check_states])
    extra = {"grid": asdict(runtime.grid), "exporter": EXPORTER, "check": asdict(report),
             "map": runtime.meta.get("map", "text"), "pool": model.pool,
             "line_vectors": model.lines}  # fmt: skip
    card = OnnxCard(
        kind=POINTER_KIND,
        graphs=specs,
        sources={name: file_sha256(directory / name) for name in SOURCES},
        opset=OPSET,
        exported_with=f"torch {torch.__version__}",
        extra=extra,
    )
    write_card(directory, card)
    return card
