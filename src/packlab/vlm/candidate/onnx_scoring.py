"""Scoring one observation's listed placements with the pointer model's ONNX graphs (ONNX
Runtime, core install: no torch, no transformers); the torch path is :mod:`.scoring`.

A step is encoded by :mod:`.encoding`, the code the torch path and training use, with the
checkpoint's ``tokenizer.json`` read by :class:`.json_tokenizer.JsonTokenizer`; the heightmap
image is patchified and normalised outside the graphs by :func:`.image.patchify`, with the
mean and std the card stores in ``extra.grid`` (the torch model's own, :class:`ImageGrid`), and
the M-RoPE position ids come from :mod:`.rope`. The vision graph turns the image into visual
tokens, and the text graph returns one score per listed line (:mod:`.onnx_graphs`, written by
:mod:`.onnx_export`).
Torch-free.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from packlab.core.errors import ConfigError
from packlab.core.types import Observation
from packlab.policies.candidates import Candidate
from packlab.policies.onnx_model import OnnxGraph, open_graphs
from packlab.vlm.candidate.compose import IMAGE_MAPS
from packlab.vlm.candidate.encoding import Encoded, ImageGrid, PromptSettings, encode_settings
from packlab.vlm.candidate.files import CANDIDATE_FORMAT
from packlab.vlm.candidate.json_tokenizer import JsonTokenizer
from packlab.vlm.candidate.rope import rope_positions

#: ``kind`` of a pointer model's ONNX card, and its graphs' names.
POINTER_KIND = "pointer"
TEXT_GRAPH, VISION_GRAPH = "text", "vision"
META_FILE = "packlab_model.json"  # packlab.vlm.model.checkpoint.PACKLAB_META (torch side)


def read_meta(directory: Path) -> dict[str, Any]:
    """A candidate-mode checkpoint's ``packlab_model.json`` (its model card)."""
    path = Path(directory) / META_FILE
    try:
        meta = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: not a readable model card ({exc})") from None
    if meta.get("action_format") != CANDIDATE_FORMAT:
        raise ConfigError(
            f"{path}: action_format = {meta.get('action_format')!r}: expected {CANDIDATE_FORMAT!r}"
        )
    return meta


def graph_names(meta: dict[str, Any]) -> tuple[str, ...]:
    """The graphs a model plays with: the text graph, and the vision graph if it sees an image."""
    image = meta.get("map", "text") in IMAGE_MAPS
    return (TEXT_GRAPH, VISION_GRAPH) if image else (TEXT_GRAPH,)


@dataclass
class OnnxPointer:
    """A pointer model ready to play on ONNX Runtime."""

    directory: Path
    meta: dict[str, Any]
    tokenizer: JsonTokenizer
    grid: ImageGrid
    graphs: dict[str, OnnxGraph]


def load_onnx_pointer(directory: str | Path, threads: int | None = 1) -> OnnxPointer:
    """The ONNX graphs of a candidate-mode checkpoint directory (``packlab export onnx`` wrote
    them); a :class:`ConfigError` names what is missing, stale or of another version."""
    directory = Path(directory)
    meta = read_meta(directory)
    card, graphs = open_graphs(directory, POINTER_KIND, graph_names(meta), threads)
    try:
        grid = ImageGrid(**card.extra["grid"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"{directory / 'onnx.json'}: field 'extra.grid' malformed ({exc!r})")
    return OnnxPointer(directory, meta, JsonTokenizer(directory), grid, graphs)


def graph_inputs(model: OnnxPointer, enc: Encoded) -> dict[str, np.ndarray]:
    """The text graph's inputs for one encoded state (running the vision graph when the state
    shows an image)."""
    feed = {
        "input_ids": enc.ids[None, :],
        "position_ids": rope_positions(enc.ids, enc.image_token, enc.grid),
        "ends": enc.ends,
        "starts": enc.starts,
        "vectors": enc.vectors,
    }
    if enc.image is not None:
        pixels, _ = model.grid.pixels(enc.image[None])
        vision = model.graphs[VISION_GRAPH].run(pixel_values=pixels)
        feed["visual_at"] = np.flatnonzero(enc.ids == enc.image_token).astype(np.int64)
        feed["visual"] = vision["visual"]
        if "deepstack" in vision:  # Qwen3-VL's deepstack features
            feed["deepstack"] = vision["deepstack"]
    return feed


def encode_step(
    model: OnnxPointer,
    observation: Observation,
    listed: Sequence[Candidate],
    settings: PromptSettings,
) -> Encoded:
    return encode_settings(model.tokenizer, observation, listed, settings, model.grid)


def score_listed(
    model: OnnxPointer,
    observation: Observation,
    listed: Sequence[Candidate],
    settings: PromptSettings,
) -> np.ndarray:
    """One score per listed placement (higher is better), as :func:`.scoring.score_listed`."""
    enc = encode_step(model, observation, listed, settings)
    return model.graphs[TEXT_GRAPH].run(**graph_inputs(model, enc))["scores"]
