"""Greedy generation for the packing VLM that reuses the conversation prefix across steps.

A closed-loop episode asks the model once per step, and each step's context X_t is the previous
one plus the previous answer and one new user turn. Re-encoding the whole history at every step
costs O(t) per step (O(t^2) per episode); :class:`PrefixCachedGenerator` keeps the model's cache
of the previous step and only feeds the tokens that are new.

How reuse is decided, each step (never by assumption, always by comparison):

1. The context is encoded exactly as :func:`packlab.vlm.data.encoding.encode` does for training
   (the same function, with the episode's :class:`~packlab.vlm.data.encoding.EncodeMemo` and an
   image processor that memoises each distinct image's pixels, so past heightmaps are
   preprocessed once per episode and past text segments tokenised once; same tensors).
2. The new token sequence is compared with the one whose state the cache holds: tokens must be
   equal *and* every image whose placeholder tokens lie in the shared prefix must be the same
   image (placeholder tokens say nothing about pixels, so images are compared by content hash).
3. The cache is brought back to the longest usable point of the shared prefix and only the rest
   is fed, with its pixel values and its own slice of the full sequence's 3-D (M-RoPE) position
   ids: the model's own ``get_rope_index`` over the tokens after the prefix shared with the
   previous prompt, continued from that prompt's positions (equal to computing them over the
   whole sequence, which tests check).
   Attention-only caches (Qwen3-VL, Qwen2.5-VL) can be cropped to any point that does not cut an
   image; Qwen3.5's gated-delta-net layers keep a recurrent state that cannot be rolled back, so
   for them the usable points are the end of what the cache holds (the previous prompt plus the
   answer, which matches when the answer re-tokenises as it was generated) and a snapshot taken
   at the start of the previous step's generation header (``<|im_start|>assistant``), which
   every next context extends whatever the answer was.
4. Anything else (first step, a new episode, a history that was cut to fit ``max_length``) is a
   full re-encode into a fresh cache.

Decoding is a plain greedy loop over the same cache (explicit position ids, no sampling), so
cached and uncached runs compute the same thing and give the same tokens; the tests check this
against ``model.generate`` too. With a batcher attached (:mod:`packlab.vlm.infer.batching`, the
``vlm`` policy's ``batch`` option) the encoding above stays the episode's own; the prefill (with
the same reuse decisions, step 3) and the loop run in a batch with other episodes' answers.
Imports torch/transformers: only the vlm extra may import this module.
"""

from __future__ import annotations

import hashlib
import time
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
from transformers import DynamicCache
from transformers.cache_utils import DynamicLayer, LinearAttentionCacheLayerMixin

from packlab.vlm.data.encoding import (
    Encoded,
    EncodeMemo,
    ProcessingConfig,
    encode,
    encode_fitting,
)

IM_START = "<|im_start|>"


def image_key(image: Any) -> tuple:
    """A content key of a PIL image (mode, size, pixel hash): equal keys mean equal pixels."""
    digest = hashlib.sha1(
        image.tobytes(), usedforsecurity=False
    ).hexdigest()  # identity, not security
    return (image.mode, image.size, digest)


class MemoImageProcessor:
    """Wraps a Qwen-VL image processor so that each distinct image is preprocessed only once.

    The Qwen2-VL-family processors treat images independently and concatenate their patches, so
    processing one image at a time and concatenating gives the same tensors as one batched call
    (tests check this). ``last_keys`` holds the content keys of the images of the latest call, in
    order; other attributes (``merge_size``, ...) are the wrapped processor's.

    An episode's calls repeat the previous call's images and add one or two: an image object seen
    before is recognised by identity (its content key is hashed once), and the patches are
    written into a buffer with room, so a call that extends the previous one copies only the new
    images' patches and returns a view (earlier views stay valid: rows are only ever appended,
    and a call that does not extend the previous one gets a new buffer).
    """

    def __init__(self, inner: Any, max_items: int = 1024) -> None:
        self.inner = inner
        self.max_items = max_items
        self.last_keys: list[tuple] = []
        self._memo: OrderedDict[tuple, tuple[torch.Tensor, torch.Tensor]] = OrderedDict()
        self._known: dict[int, tuple[Any, tuple]] = {}  # id -> (image, content key)
        self._buffer: torch.Tensor | None = None  # patches of _buffer_keys' images, then room
        self._buffer_keys: list[tuple] = []
        self._buffer_rows = 0

    def __getattr__(self, name: str) -> Any:
        if name == "inner":  # not set yet (e.g. during unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.inner, name)

    def clear(self) -> None:
        self._memo.clear()
        self._known.clear()
        self._buffer, self._buffer_keys, self._buffer_rows = None, [], 0
        self.last_keys = []

    def _key(self, image: Any) -> tuple:
        known = self._known.get(id(image))
        if known is not None and known[0] is image:
            return known[1]
        if len(self._known) >= self.max_items:
            self._known.clear()
        key = image_key(image)
        self._known[id(image)] = (image, key)
        return key

    def __call__(self, images: Sequence[Any], return_tensors: str = "pt", **kwargs: Any):
        keys, pixels, grids = [], [], []
        for im in images:
            key = self._key(im)
            hit = self._memo.get(key)
            if hit is None:
                out = self.inner(images=[im], return_tensors="pt", **kwargs)
                hit = (out["pixel_values"], out["image_grid_thw"])
                self._memo[key] = hit
                if len(self._memo) > self.max_items:
                    self._memo.popitem(last=False)
            else:
                self._memo.move_to_end(key)
            keys.append(key)
            pixels.append(hit[0])
            grids.append(hit[1])
        self.last_keys = keys
        return {"pixel_values": self._patches(keys, pixels), "image_grid_thw": torch.cat(grids)}

    def _patches(self, keys: list[tuple], pixels: list[torch.Tensor]) -> torch.Tensor:
        """``torch.cat(pixels)``, copying only what the previous call did not have."""
        held = len(self._buffer_keys)
        extends = (
            self._buffer is not None
            and held <= len(keys)
            and keys[:held] == self._buffer_keys
            and all(
                p.dtype == self._buffer.dtype and p.shape[1:] == self._buffer.shape[1:]
                for p in pixels[held:]
            )
        )
        if not extends:
            self._buffer, self._buffer_keys, self._buffer_rows, held = None, [], 0, 0
        rows = self._buffer_rows + sum(int(p.shape[0]) for p in pixels[held:])
        if self._buffer is None or rows > self._buffer.shape[0]:
            first = pixels[0]
            grown = first.new_empty((2 * rows, *first.shape[1:]))
            if self._buffer is not None:
                grown[: self._buffer_rows] = self._buffer[: self._buffer_rows]
            self._buffer = grown  # earlier views keep the old storage
        at = self._buffer_rows
        for p in pixels[held:]:
            self._buffer[at : at + p.shape[0]] = p
            at += p.shape[0]
        self._buffer_keys, self._buffer_rows = list(keys), rows
        return self._buffer[:rows]


@dataclass(frozen=True, slots=True)
class Generation:
    """One greedy answer and what it cost."""

    text: str  # decoded answer, special tokens (end of turn) removed
    token_ids: tuple[int, ...]  # generated ids, the end-of-turn token included when reached
    finished: bool  # True when an end-of-turn / eos token ended the answer
    prompt_tokens: int  # length of the encoded context
    reused_tokens: int  # context tokens whose state came from the cache (0: full encode)
    dropped_steps: int  # past steps dropped to fit max_length (encoding.encode_fitting)
    encode_s: float  # rendering to tokens and pixels
    prefill_s: float  # feeding the new context tokens (in a batch: the batch's prefill)
    decode_s: float  # the token-by-token loop (in a batch: the rest, waiting included)
    batch_rows: int = 1  # answers decoded together with this one, itself included

    @property
    def total_s(self) -> float:
        return self.encode_s + self.prefill_s + self.decode_s


@dataclass(frozen=True, slots=True)
class _Prompt:
    """One encoded context, with what the cache bookkeeping compares."""

    enc: Encoded
    ids: list[int]  # the token ids
    spans: list[tuple[int, int]]  # [start, end) of each image's tokens
    keys: list[tuple]  # content keys of the images, in order
    positions: torch.Tensor  # (4, 1, L): plain index, then M-RoPE (t, h, w)
    dropped_steps: int  # past steps dropped to fit max_length


def _image_spans(mm: list[int]) -> list[tuple[int, int]]:
    """[start, end) of each run of image tokens (one run per image: the template brackets each
    image with vision start/end tokens, so two images never touch)."""
    spans, start = [], None
    for i, v in enumerate(mm):
        if v and start is None:
            start = i
        elif not v and start is not None:
            spans.append((start, i))
            start = None
    if start is not None:
        spans.append((start, len(mm)))
    return spans


def _common_prefix(a: Sequence[int], b: Sequence[int]) -> int:
    n = min(len(a), len(b))
    ta, tb = torch.as_tensor(list(a[:n])), torch.as_tensor(list(b[:n]))
    diff = (ta != tb).nonzero()
    return int(diff[0]) if len(diff) else n


def _outside_images(p: int, spans: Sequence[tuple[int, int]]) -> int:
    """``p`` moved back to the start of the image it would cut, if any."""
    for s, e in spans:
        if s < p < e:
            return s
    return p


class _Snapshot:
    """Cache state after the first ``length`` tokens: attention lengths and cloned linear states."""

    def __init__(self, cache: Any, length: int) -> None:
        self.length = length
        self.linear: dict[int, tuple[dict, dict]] = {}
        for i, layer in enumerate(cache.layers):
            if isinstance(layer, LinearAttentionCacheLayerMixin):
                self.linear[i] = (
                    {k: None if v is None else v.clone() for k, v in layer.conv_states.items()},
                    {
                        k: None if v is None else v.clone()
                        for k, v in layer.recurrent_states.items()
                    },
                )

    def restore(self, cache: Any) -> None:
        for i, layer in enumerate(cache.layers):
            if isinstance(layer, DynamicLayer):
                extra = layer.get_seq_length() - self.length
                if extra > 0:
                    DynamicLayer.crop(layer, -extra)
            if i in self.linear:
                conv, rec = self.linear[i]
                for store, saved in ((layer.conv_states, conv), (layer.recurrent_states, rec)):
                    for k, v in saved.items():
                        if v is not None:
                            store[k].copy_(v)  # in place: keeps the snapshot itself intact


def cache_kind(cache: Any) -> str:
    """``"croppable"`` (attention layers only), ``"recurrent"`` (attention + linear-attention
    layers we can snapshot) or ``"opaque"`` (anything else: never rolled back)."""
    kinds = set()
    for layer in cache.layers:
        if isinstance(layer, LinearAttentionCacheLayerMixin):
            kinds.add("recurrent")
        elif type(layer) is DynamicLayer:
            kinds.add("croppable")
        else:
            return "opaque"
    if "recurrent" in kinds:
        # A layer that mixes both kinds in one object is not handled by _Snapshot.
        if any(
            isinstance(layer, DynamicLayer) and isinstance(layer, LinearAttentionCacheLayerMixin)
            for layer in cache.layers
        ):
            return "opaque"
        return "recurrent"
    return "croppable"


def images_between(
    prompt: _Prompt, a: int, b: int
) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """Pixel values and grids of the prompt's images whose tokens lie in [a, b) (None, None:
    none). RuntimeError where [a, b) cuts an image (a bug in the reuse plan)."""
    spans, enc = prompt.spans, prompt.enc
    if any(s < a < e or s < b < e for s, e in spans):
        raise RuntimeError(f"tokens [{a}, {b}) cut an image")
    inside = [i for i, (s, e) in enumerate(spans) if a <= s and e <= b]
    if not inside:
        return None, None
    grid = enc.image_grid_thw
    assert grid is not None and enc.pixel_values is not None  # image spans: images
    offsets = [0]
    for g in grid:
        offsets.append(offsets[-1] + int(g.prod()))
    lo, hi = inside[0], inside[-1] + 1
    return enc.pixel_values[offsets[lo] : offsets[hi]], grid[lo:hi]


def next_mrope_position(prompt: _Prompt) -> int:
    """The M-RoPE position of the first generated token: as ``generate`` does, text goes on
    after the context's largest position (an image's positions end below its token count)."""
    return int(prompt.positions[1:].max()) + 1


class PrefixCachedGenerator:
    """Greedy answers to chat contexts, reusing the previous step's cache when the new context
    extends it (see the module docstring). ``reuse_prefix=False`` re-encodes every context from
    scratch (the reference the cached path must match)."""

    def __init__(
        self,
        vlm: Any,
        config: ProcessingConfig | None = None,
        max_new_tokens: int = 64,
        reuse_prefix: bool = True,
    ) -> None:
        if max_new_tokens < 1:
            raise ValueError(f"max_new_tokens = {max_new_tokens}: must be >= 1")
        self.vlm = vlm
        self.model = vlm.model
        self.tokenizer = vlm.tokenizer
        self.config = config if config is not None else ProcessingConfig()
        self.max_new_tokens = max_new_tokens
        self.reuse_prefix = reuse_prefix
        self.processor = MemoImageProcessor(vlm.image_processor)
        self.encode_memo = EncodeMemo()
        eos = self.model.generation_config.eos_token_id
        eos_ids = set(eos if isinstance(eos, (list, tuple)) else [eos] if eos is not None else [])
        eos_ids.add(int(self.tokenizer.convert_tokens_to_ids("<|im_end|>")))
        self.eos_ids = frozenset(int(e) for e in eos_ids)
        self.im_start_id = int(self.tokenizer.convert_tokens_to_ids(IM_START))
        inner = getattr(self.model, "model", None)
        # The module whose get_rope_index gives M-RoPE positions (the inner model, else the model).
        self._rope_owner: Any = inner if hasattr(inner, "get_rope_index") else self.model
        self.device = next(self.model.parameters()).device
        #: The decode batcher of this model in this process (``packlab.vlm.infer.batching``), or
        #: None to decode alone; the policy attaches it.
        self.batcher: Any = None
        #: ``on``: every answer goes through the batcher; ``auto``: only while another episode
        #: asks the same model in this process.
        self.batch_mode = "auto"
        self.reset()

    def reset(self) -> None:
        """Forget the cache and the memoised images (call at the start of an episode)."""
        self._cache: Any = None
        self._ids: list[int] = []  # tokens whose state the cache holds
        self._spans: list[tuple[int, int]] = []  # image spans among them
        self._keys: list[tuple] = []  # content keys of those images, in order
        self._snapshot: _Snapshot | None = None
        self._last_prompt: _Prompt | None = None  # the latest encoded, for its positions
        self.processor.clear()
        self.encode_memo.clear()
        if self.batcher is not None:
            self.batcher.enter(self)

    # -- positions ---------------------------------------------------------------------------
    def _positions(self, input_ids: torch.Tensor, mm: torch.Tensor, grid: torch.Tensor | None):
        """(4, 1, L) position ids of the whole sequence: row 0 the plain index (as generate
        passes it), rows 1-3 the model's own M-RoPE (t, h, w) positions."""
        n = input_ids.shape[0]
        text = torch.arange(n, device=self.device).view(1, 1, n)
        if grid is None:
            return text.expand(4, 1, n)
        mrope, _ = self._rope_owner.get_rope_index(
            input_ids.view(1, n).to(self.device),
            mm_token_type_ids=mm.view(1, n).to(self.device),
            image_grid_thw=grid.to(self.device),
        )
        return torch.cat([text, mrope.to(self.device)], dim=0)

    def _positions_reusing(self, enc: Encoded, ids: list[int], spans) -> torch.Tensor:
        """:meth:`_positions` of the whole sequence, taking those of the tokens it shares with
        the previous prompt from that prompt: a token's positions depend only on the tokens and
        image grids before it, and the model's positions go on after an image or a text run
        from the largest position before it, so the rest's own positions shifted by that
        largest position + 1 (its plain index by the shared length) are the whole sequence's."""
        last = self._last_prompt
        grid = enc.image_grid_thw
        shared = _outside_images(_common_prefix(last.ids, ids), spans) if last else 0
        images = sum(1 for _s, e in spans if e <= shared)
        if (
            last is None
            or not self.reuse_prefix  # the reference path computes everything afresh
            or shared == 0
            or grid is None
            or last.enc.image_grid_thw is None
            or not torch.equal(last.enc.image_grid_thw[:images], grid[:images])
        ):
            return self._positions(enc.input_ids, enc.mm_token_type_ids, grid)
        head = last.positions[:, :, :shared]
        rest = self._positions(
            enc.input_ids[shared:],
            enc.mm_token_type_ids[shared:],
            grid[images:] if images < len(grid) else None,
        )
        offset = torch.tensor([shared, *[int(head[1:].max()) + 1] * 3], device=self.device)
        return torch.cat([head, rest + offset.view(4, 1, 1)], dim=2)

    # -- cache bookkeeping -------------------------------------------------------------------
    def _usable_prefix(self, ids: list[int], spans, keys) -> int:
        """How many leading tokens of ``ids`` the cache can be brought back to (0: none)."""
        if not self.reuse_prefix or self._cache is None:
            return 0
        common = _common_prefix(self._ids, ids)
        for i, (s, _e) in enumerate(spans):
            if s >= common:
                break
            if i >= len(self._keys) or self._keys[i] != keys[i]:
                common = s
                break
        limit = min(common, len(ids) - 1)  # at least one token must be fed to get logits
        kind = cache_kind(self._cache)
        points = [len(self._ids)]
        if self._snapshot is not None:
            points.append(self._snapshot.length)
        if kind == "croppable":
            points.append(_outside_images(limit, spans))
        usable = [p for p in points if 0 < p <= limit and _outside_images(p, spans) == p]
        return max(usable, default=0)

    def _bring_back(self, p: int) -> None:
        held = len(self._ids)
        if p == held:
            return
        if self._snapshot is not None and p == self._snapshot.length:
            self._snapshot.restore(self._cache)
        else:  # croppable cache
            self._cache.crop(-(held - p))
        if self._snapshot is not None and self._snapshot.length > p:
            self._snapshot = None

    def _feed(self, prompt: _Prompt, a: int, b: int) -> torch.Tensor:
        """Run tokens [a, b) of ``prompt`` through the model on the cache; logits of the last."""
        enc = prompt.enc
        kwargs: dict[str, Any] = {}
        pixels, grid = images_between(prompt, a, b)
        if pixels is not None and grid is not None:
            kwargs["pixel_values"], kwargs["image_grid_thw"] = (
                pixels.to(self.device),
                grid.to(self.device),
            )
        out = self.model(
            input_ids=enc.input_ids[a:b].view(1, -1).to(self.device),
            position_ids=prompt.positions[:, :, a:b],
            mm_token_type_ids=enc.mm_token_type_ids[a:b].view(1, -1).to(self.device),
            # transformers 5.24 renamed past_key_values (removed in 5.40) to cache (pyproject pins).
            cache=self._cache,
            use_cache=True,
            logits_to_keep=1,
            **kwargs,
        )
        return out.logits[0, -1]

    # -- the step ----------------------------------------------------------------------------
    def _encode(self, messages: Sequence[dict[str, Any]]) -> _Prompt:
        """The context as the model reads it, with its image spans, keys and positions."""
        self.processor.last_keys = []
        if self.config.max_length is not None:
            enc, dropped = encode_fitting(
                messages, self.tokenizer, self.processor, self.config, self.encode_memo
            )
        else:
            memo = self.encode_memo
            enc, dropped = encode(messages, self.tokenizer, self.processor, self.config, memo), 0
        ids = enc.input_ids.tolist()
        spans = _image_spans(enc.mm_token_type_ids.tolist())
        prompt = _Prompt(
            enc=enc,
            ids=ids,
            spans=spans,
            keys=list(self.processor.last_keys) if enc.image_grid_thw is not None else [],
            positions=self._positions_reusing(enc, ids, spans),
            dropped_steps=dropped,
        )
        self._last_prompt = prompt
        return prompt

    def _rewind(self, prompt: _Prompt) -> int:
        """Bring the cache back to the longest prefix of ``prompt`` it can keep (a fresh cache
        when none); how many prompt tokens it then holds."""
        p = self._usable_prefix(prompt.ids, prompt.spans, prompt.keys)
        if p:
            self._bring_back(p)
        else:
            self._cache = DynamicCache(config=self.model.config)
            self._snapshot = None
        return p

    def _prefill(self, prompt: _Prompt) -> tuple[torch.Tensor, int]:
        """Bring the cache to the longest usable prefix and feed the rest of the prompt.

        Returns (logits of the prompt's last token, prompt tokens reused from the cache)."""
        ids, n = prompt.ids, len(prompt.ids)
        p = self._rewind(prompt)
        kind = cache_kind(self._cache)
        # Where to snapshot a cache that cannot be cropped: the start of the generation header.
        header = next((i for i in range(n - 1, -1, -1) if ids[i] == self.im_start_id), -1)
        chunks = [(p, n)]
        if self.reuse_prefix and kind != "croppable" and p < header < n:
            chunks = [(p, header), (header, n)]
        for a, b in chunks:
            logits = self._feed(prompt, a, b)
            if b == header and cache_kind(self._cache) == "recurrent":
                self._snapshot = _Snapshot(self._cache, header)
        return logits, p

    def _decode(self, prompt: _Prompt, logits: torch.Tensor) -> tuple[list[int], bool]:
        """Greedy tokens after the prompt: (generated ids, whether an end token ended them)."""
        n = len(prompt.ids)
        generated: list[int] = []
        next_mrope = next_mrope_position(prompt)
        while True:
            tok = int(torch.argmax(logits))
            generated.append(tok)
            if tok in self.eos_ids:
                return generated, True
            if len(generated) >= self.max_new_tokens:
                return generated, False
            k = len(generated) - 1  # index of tok among the generated tokens
            step_pos = torch.tensor([n + k] + [next_mrope + k] * 3, device=self.device).view(
                4, 1, 1
            )
            out = self.model(
                input_ids=torch.tensor([[tok]], device=self.device),
                position_ids=step_pos,
                cache=self._cache,
                use_cache=True,
            )
            logits = out.logits[0, -1]

    @torch.inference_mode()
    def generate(self, messages: Sequence[dict[str, Any]]) -> Generation:
        """The greedy answer to ``messages`` (a context ending with the current user turn)."""
        t0 = time.perf_counter()
        prompt = self._encode(messages)
        t1 = time.perf_counter()
        if self.batcher is None:
            logits, reused = self._prefill(prompt)
            t2 = time.perf_counter()
            generated, finished = self._decode(prompt, logits)
            rows = 1
        else:  # prefilled and decoded by the batcher, maybe together with other episodes
            answer = self.batcher.answer(self, prompt)
            generated, finished, rows, reused = (
                answer.generated,
                answer.finished,
                answer.rows,
                answer.reused,
            )
            t2 = t1 + answer.prefill_s
        t3 = time.perf_counter()

        # The cache now holds the context and every generated token but the last.
        self._ids = prompt.ids + generated[:-1]
        self._spans, self._keys = prompt.spans, prompt.keys
        if not self.reuse_prefix:
            self._cache, self._snapshot = None, None
        answer = generated[:-1] if finished else generated
        text = self.tokenizer.decode(answer, skip_special_tokens=True)
        return Generation(
            text=text,
            token_ids=tuple(generated),
            finished=finished,
            prompt_tokens=len(prompt.ids),
            reused_tokens=reused,
            dropped_steps=prompt.dropped_steps,
            encode_s=t1 - t0,
            prefill_s=t2 - t1,
            decode_s=t3 - t2,
            batch_rows=rows,
        )

    def drop_cache(self) -> None:
        """Forget the cache (not the memoised images): the next step encodes its whole context.
        For a step whose decode failed part-way, after which the cache's state is unknown."""
        self._cache, self._ids, self._spans, self._keys = None, [], [], []
        self._snapshot = None
