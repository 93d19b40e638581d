"""The pointer model rewritten as two export-friendly modules (the graphs of the ONNX export).

- :class:`VisionGraph`: ``pixel_values`` of the one fixed-size heightmap image -> the merged
  visual token embeddings and Qwen3-VL's deepstack features (one per deepstack layer). The image
  grid is a constant, so everything that depends on it (position embeddings, rotary angles,
  attention windows) becomes a constant of the graph.
- :class:`TextGraph`: token ids, the M-RoPE position ids (computed outside the graph,
  :mod:`.rope`), the listed lines' token positions and vectors, and (models with an image) the
  visual embeddings with the positions of the image pads -> one score per listed line. The
  sequence length and the number of listed lines are dynamic. A pointer model that reads each
  line's last token (``pool`` = last) needs the last decoder layer's output at those tokens
  only: of the Qwen3-VL family, that layer's keys and values are made for every token and its
  queries, attention output and MLP for the listed lines' last tokens alone
  (:func:`layer_at_rows`), which saves about a fifth of the text graph's time. It takes the
  layer's own submodules and attention function, and each row it keeps goes through the same
  operations on the same numbers as in the whole layer: on ONNX Runtime every score equals the
  whole layer's bit for bit (``tests/vlm/test_candidate_onnx.py`` checks it), so no pick
  changes.

Both call the transformers model's own submodules (embedding, decoder layers, norm, rotary
embedding, the vision tower, the pointer head), so the graphs hold exactly the trained weights;
only the glue that transformers writes with data-dependent Python (placeholder masks,
``get_rope_index``, boolean-mask scatters) is replaced by index arithmetic on explicit inputs.
Imports torch: only the vlm extra may import this module.
"""

from __future__ import annotations

import torch
from torch import nn
from transformers.models.qwen3_vl import modeling_qwen3_vl as qwen3_vl

from packlab.vlm.candidate.pointer import PointerModel

#: The families whose last decoder layer the text graph runs at the listed lines' rows only
#: (:func:`layer_at_rows` follows their layer's code; Qwen2.5-VL applies M-RoPE in its attention).
ROWS_ONLY_FAMILIES = ("qwen3_vl",)

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


def layer_at_rows(
    layer: nn.Module,
    hidden: torch.Tensor,
    rope: tuple[torch.Tensor, torch.Tensor],
    mask: torch.Tensor,
    rows: torch.Tensor,
) -> torch.Tensor:
    """A Qwen3-VL decoder layer's output (1, R, H) at ``rows`` of ``hidden`` (1, T, H): its
    code (``Qwen3VLTextDecoderLayer``, ``Qwen3VLTextAttention``) with the queries, the residual
    stream and the MLP taken at ``rows``, the keys and values at every token."""
    attn = layer.self_attn
    shape = (1, -1, attn.config.num_attention_heads, attn.head_dim)
    kv_shape = (1, -1, attn.config.num_key_value_heads, attn.head_dim)
    normed = layer.input_layernorm(hidden)
    query = attn.q_norm(attn.q_proj(normed[:, rows]).view(shape)).transpose(1, 2)
    key = attn.k_norm(attn.k_proj(normed).view(kv_shape)).transpose(1, 2)
    value = attn.v_proj(normed).view(kv_shape).transpose(1, 2)
    cos, sin = (r.unsqueeze(1) for r in rope)  # apply_rotary_pos_emb, with the rows' angles
    query = query * cos[:, :, rows] + qwen3_vl.rotate_half(query) * sin[:, :, rows]
    key = key * cos + qwen3_vl.rotate_half(key) * sin
    attend = qwen3_vl.ALL_ATTENTION_FUNCTIONS.get_interface(
        attn.config._attn_implementation, qwen3_vl.eager_attention_forward
    )
    out, _ = attend(attn, query, key, value, mask[:, :, rows], dropout=0.0, scaling=attn.scaling)
    hidden = hidden[:, rows] + attn.o_proj(out.reshape(1, rows.shape[0], -1).contiguous())
    return hidden + layer.mlp(layer.post_attention_layernorm(hidden))


class TextGraph(nn.Module):
    """The language model and the pointer head on one state (module docstring)."""

    def __init__(self, pointer: PointerModel, image: bool) -> None:
        super().__init__()
        self.text = pointer.text
        self.head = pointer.head
        self.lines, self.pool, self.image = pointer.lines, pointer.pool, image
        self.deepstack_layers = deepstack_layers(pointer) if image else 0
        self.names = text_inputs(image, pointer.lines, pointer.pool, self.deepstack_layers > 0)
        #: The last layer at the lines' last tokens only (module docstring); not where a
        #: deepstack feature is added after it.
        self.rows_only = (
            pointer.pool == "last"
            and pointer.vlm.family in ROWS_ONLY_FAMILIES
            and len(self.text.layers) > self.deepstack_layers
        )

    def _embed(self, input_ids: torch.Tensor, extra: dict[str, torch.Tensor]) -> torch.Tensor:
        hidden = self.text.embed_tokens(input_ids)
        if self.image:  # the visual tokens take the image pads' places (batch of one)
            hidden = hidden.index_copy(1, extra["visual_at"], extra["visual"].unsqueeze(0))
        return hidden

    def hidden(
        self,
        input_ids: torch.Tensor,
        position_ids: torch.Tensor,
        extra: dict[str, torch.Tensor],
        rows: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """The final hidden states (1, T, H); given ``rows``, the last layer runs at those rows
        only (:func:`layer_at_rows`) and the states are theirs (1, R, H)."""
        hidden = self._embed(input_ids, extra)
        rope = self.text.rotary_emb(hidden, position_ids)
        mask = causal_mask(input_ids.shape[1], hidden)
        layers = list(self.text.layers)
        for n, layer in enumerate(layers if rows is None else layers[:-1]):
            hidden = layer(hidden, position_embeddings=rope, attention_mask=mask)
            if n < self.deepstack_layers:  # Qwen3-VL's deepstack: add a vision layer's features
                hidden = hidden.index_add(1, extra["visual_at"], extra["deepstack"][n].unsqueeze(0))
        if rows is not None:
            hidden = layer_at_rows(layers[-1], hidden, rope, mask, rows)
        return self.text.norm(hidden)

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        """Inputs in the order of :attr:`names` (positional, so both exporters take them)."""
        x = dict(zip(self.names, inputs, strict=True))
        ends = x["ends"]
        if self.rows_only:
            # One row more than the lines (the first again, dropped after): with a single
            # listed line, ONNX Runtime would take its matrix-vector product, whose sums round
            # otherwise than the matrix product every row of the whole layer gets.
            rows = torch.cat([ends, ends[:1]])
            picked = self.hidden(x["input_ids"], x["position_ids"], x, rows)[0, :-1]
        else:
            picked = self._pooled(self.hidden(x["input_ids"], x["position_ids"], x)[0], ends, x)
        picked = picked.unsqueeze(0)  # (1, K, H)
        if self.lines:
            valid = torch.ones_like(ends, dtype=torch.bool).unsqueeze(0)
            return self.head(picked, x["vectors"].unsqueeze(0), valid)[0, :, 0]
        return self.head(picked)[0, :, 0]

    def _pooled(
        self, hidden: torch.Tensor, ends: torch.Tensor, x: dict[str, torch.Tensor]
    ) -> torch.Tensor:
        """(K, H) of the hidden states (T, H): each listed line's last token's state, or
        (``pool`` = mean) the mean over its tokens."""
        if self.pool == "mean":
            starts = x["starts"]
            total = torch.cumsum(hidden, dim=0)
            before = total[(starts - 1).clamp(min=0)] * (starts > 0).unsqueeze(-1)
            return (total[ends] - before) / (ends - starts + 1).unsqueeze(-1)
        return hidden[ends]
