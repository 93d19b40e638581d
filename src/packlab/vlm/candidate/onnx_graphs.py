"""The pointer model rewritten as two export-friendly modules (the graphs of the ONNX export).

- :class:`VisionGraph`: ``pixel_values`` of the one fixed-size heightmap image -> the merged
  visual token embeddings and Qwen3-VL's deepstack features (one per deepstack layer). The image
  grid is a constant, so everything that depends on it (position embeddings, rotary angles,
  attention windows) becomes a constant of the graph.
- :class:`TextGraph`: token ids, the M-RoPE position ids (computed outside the graph,
  :mod:`.rope`), the listed lines' token positions and vectors, and (models with an image) the
  visual embeddings with the positions of the image pads -> one score per listed line. The
  sequence length and the number of listed lines are dynamic.

Both call the transformers model's own submodules (embedding, decoder layers, norm, rotary
embedding, the vision tower, the pointer head), so the graphs hold exactly the trained weights;
only the glue that transformers writes with data-dependent Python (placeholder masks,
``get_rope_index``, boolean-mask scatters) is replaced by index arithmetic on explicit inputs.
Imports torch: only the vlm extra may import this module.
"""

from __future__ import annotations

import torch
from torch import nn

from packlab.vlm.candidate.pointer import PointerModel

#: The graphs' input and output names (the card records them; the runtime feeds them).
VISION_INPUTS = ("pixel_values",)
VISION_OUTPUTS = ("visual", "deepstack")  # deepstack: Qwen3-VL's only
TEXT_INPUTS = ("input_ids", "position_ids", "ends")
MEAN_INPUTS = ("starts",)  # the first token of each line (``pool`` = mean only)
LINE_INPUTS = ("vectors",)
IMAGE_INPUTS = ("visual_at", "visual", "deepstack")
TEXT_OUTPUTS = ("scores",)


def deepstack_layers(pointer: PointerModel) -> int:
    """How many decoder layers add a vision layer's features (Qwen3-VL's deepstack; 0 for the
    families without it)."""
    vision = pointer.vlm.model.config.vision_config
    return len(getattr(vision, "deepstack_visual_indexes", ()))


def text_inputs(image: bool, lines: bool, pool: str, deepstack: bool) -> tuple[str, ...]:
    """The text graph's inputs, in order: only those the model reads (an exporter drops unused
    inputs, and the card must name the graph's own)."""
    mean = MEAN_INPUTS if pool == "mean" else ()
    shown = IMAGE_INPUTS if deepstack else IMAGE_INPUTS[:-1]
    return TEXT_INPUTS + mean + (LINE_INPUTS if lines else ()) + (shown if image else ())


class VisionGraph(nn.Module):
    """The vision tower on one image of a fixed grid (module docstring)."""

    def __init__(self, pointer: PointerModel, grid_thw: tuple[int, int, int]) -> None:
        super().__init__()
        self.visual = pointer.visual
        self.register_buffer("grid_thw", torch.tensor([grid_thw], dtype=torch.long))
        self.outputs = VISION_OUTPUTS if deepstack_layers(pointer) else VISION_OUTPUTS[:1]

    def forward(self, pixel_values: torch.Tensor) -> tuple[torch.Tensor, ...]:
        out = self.visual(pixel_values, grid_thw=self.grid_thw, return_dict=True)
        if len(self.outputs) == 1:
            return (out.pooler_output,)
        return out.pooler_output, torch.stack(list(out.deepstack_features))


def causal_mask(length: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """(1, 1, T, T) additive mask: 0 on and below the diagonal, the dtype's minimum above."""
    at = torch.arange(length, device=like.device)
    above = at.unsqueeze(0) > at.unsqueeze(1)
    low = torch.finfo(like.dtype).min
    return torch.zeros((), dtype=like.dtype).masked_fill(above, low)[None, None]


class TextGraph(nn.Module):
    """The language model and the pointer head on one state (module docstring)."""

    def __init__(self, pointer: PointerModel, image: bool) -> None:
        super().__init__()
        self.text = pointer.text
        self.head = pointer.head
        self.lines, self.pool, self.image = pointer.lines, pointer.pool, image
        self.deepstack_layers = deepstack_layers(pointer) if image else 0
        self.names = text_inputs(image, pointer.lines, pointer.pool, self.deepstack_layers > 0)

    def _embed(self, input_ids: torch.Tensor, extra: dict[str, torch.Tensor]) -> torch.Tensor:
        hidden = self.text.embed_tokens(input_ids)
        if self.image:  # the visual tokens take the image pads' places (batch of one)
            hidden = hidden.index_copy(1, extra["visual_at"], extra["visual"].unsqueeze(0))
        return hidden

    def hidden(
        self, input_ids: torch.Tensor, position_ids: torch.Tensor, extra: dict[str, torch.Tensor]
    ) -> torch.Tensor:
        hidden = self._embed(input_ids, extra)
        rope = self.text.rotary_emb(hidden, position_ids)
        mask = causal_mask(input_ids.shape[1], hidden)
        for n, layer in enumerate(self.text.layers):
            hidden = layer(hidden, position_embeddings=rope, attention_mask=mask)
            if n < self.deepstack_layers:  # Qwen3-VL's deepstack: add a vision layer's features
                hidden = hidden.index_add(1, extra["visual_at"], extra["deepstack"][n].unsqueeze(0))
        return self.text.norm(hidden)

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        """Inputs in the order of :attr:`names` (positional, so both exporters take them)."""
        x = dict(zip(self.names, inputs, strict=True))
        ends = x["ends"]
        hidden = self.hidden(x["input_ids"], x["position_ids"], x)[0]  # (T, H)
        if self.pool == "mean":
            starts = x["starts"]
            total = torch.cumsum(hidden, dim=0)
            before = total[(starts - 1).clamp(min=0)] * (starts > 0).unsqueeze(-1)
            picked = (total[ends] - before) / (ends - starts + 1).unsqueeze(-1)
        else:
            picked = hidden[ends]
        picked = picked.unsqueeze(0)  # (1, K, H)
        if self.lines:
            valid = torch.ones_like(ends, dtype=torch.bool).unsqueeze(0)
            return self.head(picked, x["vectors"].unsqueeze(0), valid)[0, :, 0]
        return self.head(picked)[0, :, 0]
