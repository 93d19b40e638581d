"""Greedy answers to several episodes' prompts together, through one copy of a model.

``packlab bench --concurrency N`` plays up to N episodes per worker process, one thread each, and
every ``vlm`` policy of the process asks the same loaded model (``runtime._LOADED``). Alone, each
answer is a prefill and a loop of batch-1 forwards; the forwards of N threads then contend for
the same cores (and the interpreter lock) and pay the per-forward overhead N times. A
:class:`DecodeBatcher` (one per model and process) gathers the prompts that are ready at the same
moment and runs their prefills and token loops as one batch, in a thread of its own.

What is batched, and what is not:

* Each episode renders and encodes its own context in its own thread. The batcher then brings
  each row's key-value cache back to the longest prefix it can reuse, with the same decisions as
  :class:`~packlab.vlm.infer.generate.PrefixCachedGenerator` alone: batching keeps prefix
  caching.
* The batch cache is ragged: row b's keys and values fill the first length_b columns of buffers
  with room for the tokens to come, and each forward gives every row its own number of new
  tokens (right-aligned in the inputs; a shorter row's first inputs are padding, never written
  to its cache). Attention runs row by row over each row's own columns (an ``AttentionInterface``
  function wrapping the model's own implementation, :func:`enable_ragged_batches`; forwards
  outside a batch run that implementation unchanged), so no row pays for another row's length,
  nothing is padded inside a row and no position moves; each row keeps its own M-RoPE
  positions.
* Attention-only caches (Qwen3-VL, Qwen2.5-VL) are prefilled as one batch, the rows' images fed
  together to the vision tower (each image is encoded on its own there). Qwen3.5's gated
  delta-net layers keep a recurrent state that padding inputs would change, so its rows are
  prefilled one by one and only decoded together (a decode step feeds every row exactly one
  token, and their fixed-size states are stacked as they are).
* Rows stop on their own: at an end-of-turn token or their ``max_new_tokens``. A row that stops
  is cut out of the batch at once, with its cache as it would be after answering alone (context
  plus generated tokens, the last excepted), and handed back to its episode for the next step.
* Greedy and deterministic: each row's tokens are the tokens it gets alone, up to
  floating-point ties (a batched matrix product may round differently from a batch of one;
  float32 tiny models give identical answers, which the tests check).

Gathering: the first prompt ready starts a batch; the batcher then waits for the other episodes
active on the model (an episode is active from its reset while its policy is alive and it asked
within the last ``idle_s``), up to ``max_batch`` rows, and stops waiting as soon as every one is
in, or after the longer of ``wait_s`` (a few milliseconds) and the time the previous batch
took. Waiting longer than that would cost more than it saves (a prompt that misses the batch
is answered in the next one); and while an episode prepares its prompt (rendering, encoding,
physics) it keeps the cores busy, so on a saturated machine the wait costs no throughput at all.
While a batch runs, the prompts that become ready queue up and form the next one.

``mode``: ``on`` sends every prompt through the batcher; ``auto`` (the policy's default) only
when another episode is active on the model in this process, so a single episode (``--concurrency
1``) is answered alone in its own thread with no hand-off or wait. A batch whose forward fails
(for example out of memory at that batch size) is answered again row by row, each from an empty
cache; an error then reaches only its own row. A model whose attention implementation is not a
registered one (``eager``) is answered row by row too.

Imports torch/transformers: only the vlm extra may import this module.
"""

from __future__ import annotations

import contextvars
import copy
import json
import logging
import os
import queue
import threading
import time
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from transformers import DynamicCache
from transformers.cache_utils import DynamicLayer, LinearAttentionCacheLayerMixin

from packlab.vlm.infer.generate import cache_kind, images_between, next_mrope_position

log = logging.getLogger(__name__)

#: The batch modes a policy takes (``off``: no batcher at all; the policy's BATCH_MODES).
MODES = ("auto", "on", "off")
#: Most answers decoded together (the policy's DEFAULT_MAX_BATCH).
DEFAULT_MAX_BATCH = 8
#: How long a batch waits for the active episodes not in yet: this, or as long as the previous
#: batch's decode took where that is longer (module docstring: gathering).
DEFAULT_WAIT_S = 0.005
#: Never wait longer than this for more answers.
_LONGEST_WAIT_S = 2.0
#: An episode that has not asked for this long no longer counts as active.
DEFAULT_IDLE_S = 2.0
#: How often a waiting episode checks that the batcher is alive (and lets an episode time limit,
#: raised into its thread, land).
_POLL_S = 0.05
#: Where batchers append one JSON line per batch (:func:`record_batches`); None: nowhere.
_BATCH_LOG: Path | None = None


def record_batches(path: str | os.PathLike[str] | None) -> None:
    """Have every batcher of this process (and of processes forked from it) append one JSON line
    per batch to ``path``: ``{"pid", "rows", "steps", "batch_s"}`` (``batch_s``: its prefill and
    decode); None stops it. For measurements (``benchmarks/vlm_batched_throughput.py``)."""
    global _BATCH_LOG
    _BATCH_LOG = None if path is None else Path(path)


@dataclass(frozen=True, slots=True)
class BatchStats:
    """What a batcher has decoded so far."""

    batches: int  # batched decodes run
    rows: int  # answers in them
    largest: int  # most rows in one batch

    @property
    def mean_rows(self) -> float:
        return self.rows / self.batches if self.batches else 0.0


# -- the batched prefill and decode (batcher thread) ---------------------------------------------


@dataclass(slots=True)
class _Row:
    """One answer being decoded: its generator (cache, end tokens, budget) and prompt."""

    gen: Any  # PrefixCachedGenerator
    prompt: Any  # its _Prompt
    generated: list[int]
    finished: bool = False

    def done(self) -> bool:
        """Whether the last token ends the answer (sets ``finished`` for an end token)."""
        self.finished = self.generated[-1] in self.gen.eos_ids
        return self.finished or len(self.generated) >= self.gen.max_new_tokens


@dataclass(frozen=True, slots=True)
class Answer:
    """What the batcher hands back to an episode for one prompt."""

    generated: list[int]  # greedy token ids, the end token included when reached
    finished: bool  # an end token ended them
    rows: int  # answers prefilled or decoded together with this one, itself included
    reused: int  # prompt tokens whose state came from the episode's cache
    prefill_s: float  # wall time of the prefill (the batch's, when batched)


# A batch cache is ragged: row b's attention keys and values fill columns [0, length_b) of
# buffers as wide as the longest row plus room, the rest is unused. Each forward feeds every row
# its own number of new tokens, right-aligned in the (B, N) inputs (a shorter row's first inputs
# are padding); its cache layers write the real ones after the row's length, and the attention
# computes each row over its own columns only. Nothing is padded inside a row, so no position
# moves, no mask hides anything, and no row pays for another row's length.


@dataclass(frozen=True, slots=True)
class _RaggedStep:
    """One forward of a ragged batch: where each row's new tokens go, and how many there are."""

    starts: list[int]  # row b's new keys go to columns [starts[b], starts[b] + fresh[b])
    fresh: list[int]  # real new tokens of each row (right-aligned in the inputs)

    @property
    def ends(self) -> list[int]:
        return [s + n for s, n in zip(self.starts, self.fresh, strict=True)]


#: The ragged forward running in this thread (None: an ordinary forward).
_STEP: contextvars.ContextVar[_RaggedStep | None] = contextvars.ContextVar(
    "packlab_ragged_step", default=None
)
#: The 4-D mask passed with a ragged forward: a prepared mask, which the model hands to the
#: attention as it is (its content is not read), so no padding mask is built for the batch.
_NO_MASK = torch.ones(1, 1, 1, 1, dtype=torch.bool)
_RAGGED_PREFIX = "packlab_ragged+"


def _ragged_attention(inner: str) -> Any:
    """An attention function for ``AttentionInterface``: in a ragged forward, each row over its
    own columns (torch's scaled dot-product attention, causal from the row's cached length);
    otherwise exactly ``inner`` (the model's own implementation), so answers decoded alone are
    untouched."""
    from transformers.modeling_utils import ALL_ATTENTION_FUNCTIONS

    def attention(module, query, key, value, attention_mask, scaling=None, **kwargs):
        step = _STEP.get()
        if step is None:
            return ALL_ATTENTION_FUNCTIONS[inner](
                module, query, key, value, attention_mask, scaling=scaling, **kwargs
            )
        width = query.shape[2]
        gqa = query.shape[1] != key.shape[1]
        parts = []
        for b, (start, n) in enumerate(zip(step.starts, step.fresh, strict=True)):
            end = start + n
            mask = None
            if n > 1 and start > 0:  # causal, aligned to the row's last column
                rows = torch.arange(start, end, device=query.device)[:, None]
                mask = (torch.arange(end, device=query.device)[None, :] <= rows)[None, None]
            parts.append(
                torch.nn.functional.scaled_dot_product_attention(
                    query[b : b + 1, :, width - n :],
                    key[b : b + 1, :, :end],
                    value[b : b + 1, :, :end],
                    attn_mask=mask,
                    is_causal=n > 1 and start == 0,
                    scale=scaling,
                    enable_gqa=gqa,
                ).transpose(1, 2)  # (1, n, heads, dim)
            )
        if width == 1:
            return torch.cat(parts), None
        out = query.new_zeros(query.shape[0], width, query.shape[1], query.shape[3])
        for b, (part, n) in enumerate(zip(parts, step.fresh, strict=True)):
            out[b, width - n :] = part[0]
        return out, None

    return attention


def enable_ragged_batches(model: Any) -> bool:
    """Let ``model``'s text attention run ragged batches: an ``AttentionInterface`` function that
    wraps its implementation (forwards outside a batch run exactly that). False where that
    implementation is not a registered one (``eager``: each model has its own)."""
    from transformers.masking_utils import ALL_MASK_ATTENTION_FUNCTIONS
    from transformers.modeling_utils import ALL_ATTENTION_FUNCTIONS

    config = getattr(model.config, "text_config", None) or model.config
    inner = config._attn_implementation or "sdpa"
    if inner.startswith(_RAGGED_PREFIX):
        return True
    if inner not in ALL_ATTENTION_FUNCTIONS or inner not in ALL_MASK_ATTENTION_FUNCTIONS:
        return False
    name = _RAGGED_PREFIX + inner
    with _REGISTER_LOCK:
        if name not in ALL_ATTENTION_FUNCTIONS:
            ALL_ATTENTION_FUNCTIONS.register(name, _ragged_attention(inner))
            ALL_MASK_ATTENTION_FUNCTIONS.register(name, ALL_MASK_ATTENTION_FUNCTIONS[inner])
        config._attn_implementation = name
    return True


_REGISTER_LOCK = threading.Lock()


class _RaggedLayer(DynamicLayer):
    """An attention layer of a ragged batch cache (see above): buffers with room for the tokens
    to come, written in place where a plain :class:`DynamicLayer` would copy the whole cache."""

    def __init__(self, keys: torch.Tensor, values: torch.Tensor, room: int) -> None:
        super().__init__()
        self.lazy_initialization(keys, values)
        self._k, self._v = keys, values
        self._width = keys.shape[2]  # columns in use (the longest row)
        self._grow(self._width + room)

    def _grow(self, capacity: int) -> None:
        if capacity > self._k.shape[2]:
            shape = (*self._k.shape[:2], capacity, self._k.shape[3])
            k, v = self._k.new_zeros(shape), self._v.new_zeros(shape)
            k[:, :, : self._width] = self._k[:, :, : self._width]
            v[:, :, : self._width] = self._v[:, :, : self._width]
            self._k, self._v = k, v
        self.keys, self.values = self._k[:, :, : self._width], self._v[:, :, : self._width]

    def update(
        self, key_states: torch.Tensor, value_states: torch.Tensor, *args: Any, **kwargs: Any
    ) -> tuple[torch.Tensor, torch.Tensor]:
        step = _STEP.get()
        if step is None:
            raise RuntimeError("a ragged batch cache used outside a ragged forward")
        ends = step.ends
        self._width = max(self._width, *ends)
        self._grow(self._width)
        width = key_states.shape[2]
        if width == 1:  # a decode step: one token per row, one indexed write
            rows = torch.arange(len(ends), device=self._k.device)
            cols = torch.tensor(step.starts, device=self._k.device)
            self._k[rows, :, cols] = key_states[:, :, 0]
            self._v[rows, :, cols] = value_states[:, :, 0]
        else:
            for b, (start, n) in enumerate(zip(step.starts, step.fresh, strict=True)):
                self._k[b, :, start : start + n] = key_states[b, :, width - n :]
                self._v[b, :, start : start + n] = value_states[b, :, width - n :]
        return self.keys, self.values

    def keep(self, rows: torch.Tensor, width: int) -> None:
        """Keep only ``rows``, now at most ``width`` columns long (room kept)."""
        self._k, self._v = self._k[rows], self._v[rows]
        self._width = width
        self._grow(0)

    def row(self, b: int, length: int) -> DynamicLayer:
        """Row ``b``'s first ``length`` columns as a batch-1 layer of its own."""
        new = DynamicLayer()
        keys = self._k[b : b + 1, :, :length].clone()
        new.lazy_initialization(keys, keys)
        new.keys, new.values = keys, self._v[b : b + 1, :, :length].clone()
        return new


def _copy_layer(layer: Any) -> Any:
    """A shallow copy of a cache layer whose dicts (per-state tensors, flags) are its own."""
    new = copy.copy(layer)
    for name, value in vars(layer).items():
        if isinstance(value, dict):
            setattr(new, name, dict(value))
    return new


def _ragged_cache(caches: Sequence[Any], lengths: Sequence[int], room: int) -> Any:
    """One ragged batch cache of batch-1 caches holding ``lengths`` tokens each (a fresh cache:
    0), with room for ``room`` more columns; linear-attention states stacked as they are."""
    layers = []
    width = max(lengths)
    for parts in zip(*(c.layers for c in caches), strict=True):
        if isinstance(parts[0], LinearAttentionCacheLayerMixin):
            new = _copy_layer(parts[0])
            for store in ("conv_states", "recurrent_states"):
                states = getattr(new, store)
                for k, v in states.items():
                    if v is not None:
                        states[k] = torch.cat([getattr(p, store)[k] for p in parts])
        else:
            ref = next((p for p in parts if p.is_initialized), None)
            if ref is None:  # every row is fresh: shapes from the model's config below
                new = _LazyRaggedLayer(len(parts), room)
            else:
                heads, dim = ref.keys.shape[1], ref.keys.shape[3]
                keys = ref.keys.new_zeros(len(parts), heads, width, dim)
                values = ref.values.new_zeros(len(parts), heads, width, dim)
                for i, (p, n) in enumerate(zip(parts, lengths, strict=True)):
                    if n:
                        assert p.keys.shape[2] == n  # the cache holds exactly its prefix
                        keys[i, :, :n] = p.keys[0]
                        values[i, :, :n] = p.values[0]
                new = _RaggedLayer(keys, values, room)
        layers.append(new)
    batch = copy.copy(caches[0])
    batch.layers = layers
    return batch


class _LazyRaggedLayer(DynamicLayer):
    """A ragged layer whose rows are all empty: it becomes a :class:`_RaggedLayer` (in place,
    by class) at its first update, when the keys' shape is known."""

    def __init__(self, rows: int, room: int) -> None:
        super().__init__()
        self._rows, self._room = rows, room

    def update(self, key_states, value_states, *args, **kwargs):
        empty = key_states.new_zeros(self._rows, key_states.shape[1], 0, key_states.shape[3])
        room = self._room + key_states.shape[2]
        self.__class__ = _RaggedLayer
        _RaggedLayer.__init__(self, empty, empty.clone(), room)  # type: ignore[misc]
        return self.update(key_states, value_states, *args, **kwargs)


def _keep_rows(cache: Any, rows: list[int], width: int) -> None:
    """Keep only ``rows`` of the batch cache; its attention layers ``width`` columns wide."""
    for layer in cache.layers:
        if isinstance(layer, _RaggedLayer):
            layer.keep(torch.tensor(rows, device=layer.keys.device), width)
        elif isinstance(layer, LinearAttentionCacheLayerMixin):
            for store in (layer.conv_states, layer.recurrent_states):
                for k, v in store.items():
                    if v is not None:
                        store[k] = v[torch.tensor(rows, device=v.device)]


def _take_row(cache: Any, b: int, length: int) -> Any:
    """Row ``b`` of the batch cache as a batch-1 cache of its own, ``length`` tokens long."""
    layers: list[Any] = []
    for layer in cache.layers:
        if isinstance(layer, _RaggedLayer):
            layers.append(layer.row(b, length))
        else:
            new = _copy_layer(layer)
            for store in ("conv_states", "recurrent_states"):
                states = getattr(new, store)
                for k, v in states.items():
                    if v is not None:
                        states[k] = v[b : b + 1].clone()
            layers.append(new)
    single = copy.copy(cache)
    single.layers = layers
    return single


class NotBatchable(ValueError):
    """The answers cannot be stacked into one batch; nothing was changed, each can be answered
    alone as it is."""


def _check_stackable(gens: Sequence[Any]) -> str:
    """NotBatchable unless the generators' caches can be stacked (one model whose attention runs
    ragged batches; caches of the kinds :func:`_ragged_cache` knows, or none yet); the model's
    cache kind."""
    model = gens[0].model
    if not enable_ragged_batches(model):
        raise NotBatchable("the model's attention implementation cannot run ragged batches")
    for gen in gens:
        if gen.model is not model:
            raise NotBatchable("rows of different models")
        if gen._cache is not None and cache_kind(gen._cache) == "opaque":
            raise NotBatchable("a row's cache is of a kind that cannot be stacked")
    kind = cache_kind(DynamicCache(config=model.config))
    if kind == "opaque":
        raise NotBatchable("the model's cache is of a kind that cannot be stacked")
    return kind


def answer_together(requests: Sequence[tuple[Any, Any]]) -> list[Answer]:
    """Greedy answers to encoded prompts of several generators, prefilled and decoded together.

    ``requests``: (generator, prompt) with each generator's cache as its previous step left it.
    Each prompt reuses its own cache's prefix as :meth:`PrefixCachedGenerator._prefill` would.
    Attention-only caches (Qwen3-VL, Qwen2.5-VL) are prefilled as one ragged batch; caches with
    linear-attention states (Qwen3.5), which padding would change, are prefilled row by row.
    The decode is one ragged batch either way. Each generator's cache then holds its prompt and
    its answer but the last token, as after answering alone. Raises :class:`NotBatchable`
    before touching anything when the caches cannot be stacked; after any other exception the
    caches are in an unknown state."""
    gens = [gen for gen, _ in requests]
    kind = _check_stackable(gens)
    t0 = time.perf_counter()
    room = max(gen.max_new_tokens for gen in gens)
    if kind == "croppable":
        reused = [gen._rewind(prompt) for gen, prompt in requests]
        cache = _ragged_cache(
            [gen._cache for gen in gens],
            reused,
            room + max(len(p.ids) - h for (_, p), h in zip(requests, reused, strict=True)),
        )
        for gen in gens:  # the batch cache is the only copy now
            gen._cache = None
        logits = _prefill_ragged(requests, reused, cache)
    else:
        prefilled = [gen._prefill(prompt) for gen, prompt in requests]
        reused = [p for _, p in prefilled]
        logits = [lg for lg, _ in prefilled]
        cache = None
    prefill_s = time.perf_counter() - t0
    rows = [
        _Row(gen, prompt, [int(torch.argmax(lg))])
        for (gen, prompt), lg in zip(requests, logits, strict=True)
    ]
    if cache is None:  # prefilled alone: the rows that go on are stacked for the decode
        live = [r for r in rows if not r.done()]
        if live:
            lengths = [len(r.prompt.ids) for r in live]
            cache = _ragged_cache([r.gen._cache for r in live], lengths, room)
            for r in live:
                r.gen._cache = None
            _decode_ragged(live, cache, lengths)
    else:
        _decode_ragged(rows, cache, [len(r.prompt.ids) for r in rows])
    return [
        Answer(r.generated, r.finished, len(rows), p, prefill_s)
        for r, p in zip(rows, reused, strict=True)
    ]


def _prefill_ragged(
    requests: Sequence[tuple[Any, Any]], held: Sequence[int], cache: Any
) -> list[torch.Tensor]:
    """Feed each prompt's tokens after the ``held`` its row of the ragged ``cache`` holds, every
    row in one forward; the logits of each prompt's last token."""
    gen0 = requests[0][0]
    device = gen0.device
    fresh = [len(p.ids) - h for (_, p), h in zip(requests, held, strict=True)]
    span = max(fresh)
    rows = len(requests)
    pad_id = min(gen0.eos_ids)  # any real token: padding inputs are never attended to
    ids = torch.full((rows, span), pad_id, dtype=torch.long, device=device)
    mm = torch.zeros(rows, span, dtype=torch.long, device=device)
    positions = torch.zeros(4, rows, span, dtype=torch.long, device=device)
    pixels, grids = [], []
    for i, ((_gen, prompt), h, n) in enumerate(zip(requests, held, fresh, strict=True)):
        enc, end = prompt.enc, len(prompt.ids)
        ids[i, span - n :] = enc.input_ids[h:end]
        mm[i, span - n :] = enc.mm_token_type_ids[h:end]
        positions[:, i, span - n :] = prompt.positions[:, 0, h:end]
        image_pixels, image_grids = images_between(prompt, h, end)
        if image_pixels is not None:
            pixels.append(image_pixels)
            grids.append(image_grids)
    images: dict[str, Any] = {}
    if pixels:
        images["pixel_values"] = torch.cat(pixels).to(device)
        images["image_grid_thw"] = torch.cat(grids).to(device)
    token = _STEP.set(_RaggedStep(list(held), fresh))
    try:
        out = gen0.model(
            input_ids=ids,
            position_ids=positions,
            mm_token_type_ids=mm,
            attention_mask=_NO_MASK.to(device),
            cache=cache,
            use_cache=True,
            logits_to_keep=1,
            **images,
        )
    finally:
        _STEP.reset(token)
    return list(out.logits[:, -1])


def _decode_ragged(rows: list[_Row], cache: Any, lengths: list[int]) -> None:
    """The token loop of ``rows`` (each with its first token) on the ragged batch ``cache``,
    whose row b holds ``lengths[b]`` tokens. Each row leaves the batch with its own cache as
    decoding alone would leave it."""
    gen0 = rows[0].gen
    device = gen0.device
    mrope = torch.tensor([next_mrope_position(r.prompt) for r in rows], device=device)
    plain = torch.tensor([len(r.prompt.ids) for r in rows], device=device)
    fed = 0  # tokens fed to every live row (they started together)
    while True:
        keep = [j for j, r in enumerate(rows) if not r.done()]
        if len(keep) < len(rows):
            for j, r in enumerate(rows):
                if j not in keep:
                    r.gen._cache = _take_row(cache, j, lengths[j])
            if not keep:
                return
            rows, lengths = [rows[j] for j in keep], [lengths[j] for j in keep]
            _keep_rows(cache, keep, max(lengths))
            index = torch.tensor(keep, device=device)
            mrope, plain = mrope[index], plain[index]
        tokens = torch.tensor([[r.generated[-1]] for r in rows], device=device)
        step = torch.stack([plain + fed, mrope + fed, mrope + fed, mrope + fed]).view(4, -1, 1)
        token = _STEP.set(_RaggedStep(lengths, [1] * len(rows)))
        try:
            out = gen0.model(
                input_ids=tokens,
                position_ids=step,
                attention_mask=_NO_MASK.to(device),
                cache=cache,
                use_cache=True,
            )
        finally:
            _STEP.reset(token)
        fed += 1
        lengths = [n + 1 for n in lengths]
        for r, tok in zip(rows, out.logits[:, -1].argmax(-1).tolist(), strict=True):
            r.generated.append(int(tok))


# -- gathering (episode threads and the batcher thread) -----------------------------------------


@dataclass(slots=True)
class _Request:
    """An encoded prompt waiting for its answer, and where the answer goes."""

    gen: Any
    prompt: Any
    done: threading.Event = field(default_factory=threading.Event)
    result: Answer | None = None
    error: BaseException | None = None
    cancelled: bool = False  # its episode stopped waiting (a time limit)


_STOP = object()


class DecodeBatcher:
    """Answers the prompts of one model's episodes in this process together (module docstring).

    :meth:`enter` is called by each episode's generator when the episode starts, :meth:`answer`
    in the episode's thread after each encoding; a thread of the batcher's own runs the batches.
    :meth:`stop` ends that thread (the answers still queued get an error); a later
    :meth:`answer` starts a new one.
    """

    def __init__(
        self,
        max_batch: int = DEFAULT_MAX_BATCH,
        wait_s: float = DEFAULT_WAIT_S,
        idle_s: float = DEFAULT_IDLE_S,
    ) -> None:
        if max_batch < 1:
            raise ValueError(f"max_batch = {max_batch}: must be >= 1")
        self.max_batch, self.wait_s, self.idle_s = max_batch, wait_s, idle_s
        self._lock = threading.Lock()
        self._clients: dict[int, float] = {}  # id(generator) -> when it last asked or got an answer
        self._stats = BatchStats(0, 0, 0)
        self._last_batch_s = 0.0  # wall time of the latest batch (prefill and decode)
        self._start_fresh()

    def _start_fresh(self) -> None:
        """No thread yet (also after a fork: the parent's thread does not exist here)."""
        self._pid = os.getpid()
        self._queue: queue.Queue[Any] = queue.Queue()
        self._thread: threading.Thread | None = None
        self._stopping = False

    # -- episode side ----------------------------------------------------------------------
    def answer(self, gen: Any, prompt: Any) -> Answer:
        """The greedy answer to an encoded prompt of ``gen``, whose cache afterwards holds what
        :meth:`PrefixCachedGenerator._prefill` and ``_decode`` would leave."""
        others = self._arrive(gen)
        if gen.batch_mode == "auto" and others == 0:
            try:
                return _answer_alone(gen, prompt, fresh=False)
            finally:
                self._seen(gen)
        request = _Request(gen, prompt)
        self._submit(request)
        try:
            while not request.done.wait(_POLL_S):
                thread = self._thread
                if thread is None or not thread.is_alive():
                    raise RuntimeError("the decode batcher stopped before answering")
        except BaseException:
            request.cancelled = True  # nobody reads it now; a batch not yet run skips it
            raise
        finally:
            self._seen(gen)
        if request.error is not None:
            raise request.error
        assert request.result is not None  # done without an error
        return request.result

    def enter(self, gen: Any) -> None:
        """Count ``gen``'s episode as active from now on (its generator's reset: batches wait
        for it before its first answer is ready)."""
        self._arrive(gen)

    def _arrive(self, gen: Any) -> int:
        """Count ``gen`` as an active episode; how many other episodes are active now."""
        key = id(gen)
        with self._lock:
            if key not in self._clients:
                weakref.finalize(gen, self._forget, key)  # a finished episode leaves at once
            self._clients[key] = time.monotonic()
            return self._active() - 1

    def _seen(self, gen: Any) -> None:
        with self._lock:
            if id(gen) in self._clients:
                self._clients[id(gen)] = time.monotonic()

    def _forget(self, key: int) -> None:
        with self._lock:
            self._clients.pop(key, None)

    def _active(self) -> int:
        """Episodes that asked (or were answered) within ``idle_s``; under the lock."""
        since = time.monotonic() - self.idle_s
        return sum(t >= since for t in self._clients.values())

    def _submit(self, request: _Request) -> None:
        with self._lock:
            if self._pid != os.getpid():
                self._start_fresh()
            if self._thread is None or not self._thread.is_alive():
                # A fresh queue: a stopped thread's leftovers (its stop mark) are not ours.
                self._queue, self._stopping = queue.Queue(), False
                self._thread = threading.Thread(
                    target=self._run,
                    args=(self._queue, torch.get_num_threads()),
                    name="packlab-vlm-batcher",
                    daemon=True,  # never keeps a finished process alive
                )
                self._thread.start()
            self._queue.put(request)

    # -- batcher side ----------------------------------------------------------------------
    def stats(self) -> BatchStats:
        with self._lock:
            return self._stats

    def stop(self, timeout_s: float | None = 10.0) -> None:
        """End the batcher's thread after the batch it runs; queued answers get an error."""
        with self._lock:
            thread, self._stopping = self._thread, True
            self._queue.put(_STOP)
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout_s)

    def _run(self, requests: queue.Queue[Any], threads: int) -> None:
        # Intra-op threads are per thread: use what the episodes' threads use.
        torch.set_num_threads(threads)
        while not self._stopping:
            first = requests.get()
            if first is _STOP:
                break
            batch = self._gather(requests, first)
            if batch:
                self._serve(batch)
        self._fail_queued(requests)

    def _gather(self, requests: queue.Queue[Any], first: _Request) -> list[_Request]:
        """``first`` and the answers that join it (module docstring: gathering)."""
        batch = [first]
        wait = max(self.wait_s, min(self._last_batch_s, _LONGEST_WAIT_S))
        deadline = time.monotonic() + wait
        while len(batch) < self.max_batch:
            try:
                item = requests.get_nowait()
            except queue.Empty:
                with self._lock:
                    everyone = len(batch) >= self._active()
                remaining = deadline - time.monotonic()
                if everyone or remaining <= 0:
                    break
                try:
                    item = requests.get(timeout=remaining)
                except queue.Empty:
                    break
            if item is _STOP:
                self._stopping = True
                break
            batch.append(item)
        return [r for r in batch if not r.cancelled]

    def _serve(self, batch: list[_Request]) -> None:
        """Answer ``batch`` together; row by row if that fails."""
        t0 = time.perf_counter()
        with torch.inference_mode():
            try:
                answers = answer_together([(r.gen, r.prompt) for r in batch])
            except NotBatchable as exc:
                log.info("answering %d prompts one by one: %s", len(batch), exc)
                for r in batch:
                    self._alone(r, fresh=False)
            except Exception as exc:  # noqa: BLE001 - each row is retried alone below
                log.warning(
                    "a batch of %d answers failed (%s: %s); answering them one by one",
                    len(batch),
                    type(exc).__name__,
                    exc,
                )
                for r in batch:
                    self._alone(r, fresh=True)
            else:
                for r, answer in zip(batch, answers, strict=True):
                    r.result = answer
        batch_s = time.perf_counter() - t0
        self._last_batch_s = batch_s
        with self._lock:
            s = self._stats
            self._stats = BatchStats(s.batches + 1, s.rows + len(batch), max(s.largest, len(batch)))
        steps = max((len(r.result.generated) for r in batch if r.result), default=0)
        _log_batch(len(batch), steps, batch_s)
        for r in batch:
            r.done.set()

    @staticmethod
    def _alone(r: _Request, fresh: bool) -> None:
        """Answer one prompt by itself: from its cache, or (``fresh``, after a failed batch left
        the cache in an unknown state) from an empty one. An error here is this answer's only."""
        try:
            r.result = _answer_alone(r.gen, r.prompt, fresh)
        except Exception as exc:  # noqa: BLE001 - raised in the episode's own thread
            r.gen.drop_cache()
            r.error = exc

    def _fail_queued(self, requests: queue.Queue[Any]) -> None:
        while True:
            try:
                item = requests.get_nowait()
            except queue.Empty:
                return
            if item is not _STOP:
                item.error = RuntimeError("the decode batcher stopped before answering")
                item.done.set()


def _answer_alone(gen: Any, prompt: Any, fresh: bool) -> Answer:
    """Prefill and decode one prompt on its own (``fresh``: from an empty cache)."""
    if fresh:
        gen.drop_cache()
    t0 = time.perf_counter()
    logits, reused = gen._prefill(prompt)
    prefill_s = time.perf_counter() - t0
    generated, finished = gen._decode(prompt, logits)
    return Answer(generated, finished, 1, reused, prefill_s)


def _log_batch(rows: int, steps: int, batch_s: float) -> None:
    """One line of :func:`record_batches`' file, when one is set."""
    if _BATCH_LOG is None:
        return
    line = {"pid": os.getpid(), "rows": rows, "steps": steps, "batch_s": round(batch_s, 6)}
    with _BATCH_LOG.open("a", encoding="utf-8") as f:
        f.write(json.dumps(line) + "\n")
