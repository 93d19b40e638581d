"""A trained agent played from its ONNX export on ONNX Runtime (torch-free: the core install).

``packlab export onnx DIR`` (:mod:`packlab.rl.onnx_export`, rl extra) writes ``policy.onnx``:
the policy network's greedy path, (heightmap (1, 1, G, G), globals (1, N_GLOBALS), items
(1, N, F)) float32 -> logits (1, N) float32, the raw row logits with no masking, and
``onnx.json`` (:mod:`packlab.policies.onnx_model`, kind ``rl-agent``). The decision is
:func:`packlab.rl.decision.decide`, the rule the torch runtime applies to its own logits.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from packlab.core.errors import ConfigError
from packlab.policies.onnx_model import CARD_FILE as ONNX_CARD_FILE
from packlab.policies.onnx_model import OnnxCard, OnnxGraph, export_hint, open_graphs
from packlab.rl.card import AgentCard, read_card

#: ``onnx.json``'s kind for an RL agent directory.
ONNX_KIND = "rl-agent"
#: The one graph of an agent directory, its file and its input/output names (a change here is a
#: change of contract: bump :data:`packlab.policies.onnx_model.ONNX_FORMAT`).
GRAPH = "policy"
GRAPH_FILE = "policy.onnx"
INPUTS = ("heightmap", "globals", "items")
OUTPUTS = ("logits",)


def batched(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The graph's inputs for one encoded observation: each array with a batch axis of 1."""
    return {name: np.ascontiguousarray(arrays[name], dtype=np.float32)[None] for name in INPUTS}


@dataclass(frozen=True, slots=True)
class OnnxAgent:
    """An agent directory opened for ONNX Runtime: its card, its export's card and its graph."""

    card: AgentCard
    onnx: OnnxCard
    graph: OnnxGraph

    def row_logits(self, arrays: dict[str, np.ndarray]) -> np.ndarray:
        """(N,) float32: the raw logits of one encoded observation (a
        :data:`packlab.rl.decision.RowLogits`)."""
        return self.graph.run(**batched(arrays))["logits"][0]


def load_onnx_agent(directory: Path, threads: int | None = 1) -> OnnxAgent:
    """Open ``directory``'s ONNX export (a ConfigError names what is missing or stale)."""
    directory = Path(directory)
    card = read_card(directory)
    onnx, graphs = open_graphs(directory, ONNX_KIND, [GRAPH], threads)
    # The sources' sha256 already ties the graph to this card.json; this catches a card
    # copied between directories by hand, where the file hashes cannot help.
    exported = (onnx.extra.get("agent"), onnx.extra.get("n_items"))
    if exported != (card.agent, card.n_items):
        raise ConfigError(
            f"{directory / ONNX_CARD_FILE}: exported a {exported[0]!r} agent with {exported[1]} "
            f"rows but card.json says {card.agent!r} with {card.n_items}; {export_hint(directory)}"
        )
    return OnnxAgent(card, onnx, graphs[GRAPH])
