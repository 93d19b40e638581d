"""Greedy decoding of several episodes' answers together, through one copy of a model.

``packlab bench --concurrency N`` plays up to N episodes per worker process, one thread each, and
every ``vlm`` policy of the process asks the same loaded model (``runtime._LOADED``). Alone, each
answer is a loop of batch-1 forwards; the loops of N threads then contend for the same cores and
pay the per-forward overhead N times. A :class:`DecodeBatcher` (one per model and process)
gathers the answers that are ready to decode at the same moment and runs their token loops as
one batch.

What is batched, and what is not:

* Each episode still encodes and prefills its own context in its own thread, on its own
  key-value cache, with the per-episode prefix reuse of
  :class:`~packlab.vlm.infer.generate.PrefixCachedGenerator` unchanged: batching keeps prefix
  caching. A step's new tokens are a small part of its context, so the prefill is short; the
  decode (up to ``max_new_tokens`` forwards) is where the time goes, and that is batched.
  Images only ever enter a prefill, so they never cross rows and every family batches (Qwen3.5,
  Qwen3-VL, Qwen2.5-VL; their pixel values and grids stay each row's own).
* The prefilled caches are stacked into one batch cache: attention layers' keys and values
  left-padded to the longest row, with an attention mask that hides the padding; linear-attention
  layers' fixed-size states (Qwen3.5's gated delta net) stacked as they are, since a decode
  step feeds each row exactly one token and their states never see padding. Each row keeps its
  own M-RoPE positions (its context length and its next M-RoPE position plus the tokens
  generated so far), so padding moves no position.
* Rows stop on their own: at an end-of-turn token or their ``max_new_tokens``. A row that stops
  is cut out of the batch at once, with its cache as it would be after decoding alone (context
  plus generated tokens, the last excepted), and handed back to its episode for the next step.
* Greedy and deterministic: each row's tokens are the tokens it gets alone, up to
  floating-point ties (a batched matrix product may round differently from a batch of one;
  float32 tiny models give identical answers, which the tests check).

Gathering: the first answer ready starts a batch; the batcher then waits for the other episodes
active on the model (an episode is active from its reset while its policy is alive and it asked
within the last ``idle_s``), up to ``max_batch`` rows, and stops waiting as soon as every one is
in, or after the longer of ``wait_s`` (a few milliseconds) and the time the previous batch
took to decode. Waiting longer than that would cost more than it saves (an answer that misses
the batch gets a decode loop of its own, which takes about as long); and while an episode
prepares its answer (rendering, encoding, prefilling, physics) it keeps the cores busy, so on a
saturated machine the wait costs no throughput at all. While a batch decodes, the answers that
become ready queue up and form the next one.

``mode``: ``on`` sends every answer through the batcher; ``auto`` (the policy's default) only
when another episode is active on the model in this process, so a single episode (``--concurrency
1``) decodes alone in its own thread with no hand-off or wait. A batch whose forward fails (for
example out of memory at that batch size) is decoded again row by row, each from a fresh
prefill; an error then reaches only its own row.

Imports torch/transformers: only the vlm extra may import this module.
"""

from __future__ import annotations

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
from transformers.cache_utils import DynamicLayer

from packlab.vlm.infer.generate import cache_kind, next_mrope_position

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
    per batch to ``path``: ``{"pid", "rows", "steps", "decode_s"}``; None stops it. For
    measurements (``benchmarks/vlm_batched_throughput.py``)."""
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


# -- the batched decode (batcher thread) ---------------------------------------------------------


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


def _attention_length(cache: Any) -> int | None:
    """Tokens the cache's attention layers hold (None: it has none)."""
    for layer in cache.layers:
        if type(layer) is DynamicLayer:
            return int(layer.keys.shape[-2])
    return None


class _GrowingLayer(DynamicLayer):
    """An attention layer of the batch cache: keys and values in buffers with room for the
    tokens still to come, so a decode step writes one column in place where a plain
    :class:`DynamicLayer` would copy the whole cache (``torch.cat``), for every row."""

    def fill(self, keys: torch.Tensor, values: torch.Tensor, room: int) -> None:
        """Hold ``keys``/``values`` (B, H, L, D), with space for ``room`` more tokens."""
        self.lazy_initialization(keys, values)
        shape = (*keys.shape[:2], keys.shape[2] + room, keys.shape[3])
        self._k, self._v = keys.new_empty(shape), values.new_empty(shape)
        self._k[:, :, : keys.shape[2]] = keys
        self._v[:, :, : values.shape[2]] = values
        self._view(keys.shape[2])

    def _view(self, length: int) -> None:
        self.keys, self.values = self._k[:, :, :length], self._v[:, :, :length]

    def update(
        self, key_states: torch.Tensor, value_states: torch.Tensor, *args: Any, **kwargs: Any
    ) -> tuple[torch.Tensor, torch.Tensor]:
        n, m = self.keys.shape[2], key_states.shape[2]
        if n + m > self._k.shape[2]:  # more tokens than announced: grow (never in decode)
            self.fill(self.keys, self.values, room=max(m, n))
        self._k[:, :, n : n + m] = key_states
        self._v[:, :, n : n + m] = value_states
        self._view(n + m)
        return self.keys, self.values

    def select(self, rows: torch.Tensor, start: int) -> None:
        """Keep only ``rows``, from position ``start`` on (room kept)."""
        n = self.keys.shape[2]
        self._k, self._v = self._k[rows, :, start:], self._v[rows, :, start:]
        self._view(n - start)


def _copy_layer(layer: Any) -> Any:
    """A shallow copy of a cache layer whose dicts (per-state tensors, flags) are its own."""
    new = copy.copy(layer)
    for name, value in vars(layer).items():
        if isinstance(value, dict):
            setattr(new, name, dict(value))
    return new


def _stack(caches: Sequence[Any], pads: Sequence[int], room: int) -> Any:
    """One batch cache of batch-1 caches: attention keys/values left-padded by ``pads``, with
    space for ``room`` more tokens."""
    layers = []
    for parts in zip(*(c.layers for c in caches), strict=True):
        if type(parts[0]) is DynamicLayer:
            new = _GrowingLayer()
            new.fill(
                torch.cat([_pad_left(p.keys, n) for p, n in zip(parts, pads, strict=True)]),
                torch.cat([_pad_left(p.values, n) for p, n in zip(parts, pads, strict=True)]),
                room,
            )
        else:  # linear attention: fixed-size states, no sequence axis
            new = _copy_layer(parts[0])
            for store in ("conv_states", "recurrent_states"):
                states = getattr(new, store)
                for k, v in states.items():
                    if v is not None:
                        states[k] = torch.cat([getattr(p, store)[k] for p in parts])
        layers.append(new)
    batch = copy.copy(caches[0])
    batch.layers = layers
    return batch


def _pad_left(t: torch.Tensor, n: int) -> torch.Tensor:
    """(1, H, L, D) -> (1, H, n + L, D), zeros first."""
    return torch.nn.functional.pad(t, (0, 0, n, 0)) if n else t


def _select(cache: Any, rows: list[int], start: int) -> None:
    """Keep only ``rows`` of the batch cache, attention layers from position ``start`` on."""
    for layer in cache.layers:
        if isinstance(layer, _GrowingLayer):
            layer.select(torch.tensor(rows, device=layer.keys.device), start)
        else:
            for store in (layer.conv_states, layer.recurrent_states):
                for k, v in store.items():
                    if v is not None:
                        store[k] = v[torch.tensor(rows, device=v.device)]


def _take_row(cache: Any, row: int, pad: int) -> Any:
    """Row ``row`` of the batch cache as a batch-1 cache of its own (padding removed)."""
    layers: list[Any] = []
    for layer in cache.layers:
        if isinstance(layer, _GrowingLayer):
            new = DynamicLayer()
            keys = layer.keys[row : row + 1, :, pad:].clone()
            new.lazy_initialization(keys, keys)
            new.keys, new.values = keys, layer.values[row : row + 1, :, pad:].clone()
        else:
            new = _copy_layer(layer)
            for store in ("conv_states", "recurrent_states"):
                states = getattr(new, store)
                for k, v in states.items():
                    if v is not None:
                        states[k] = v[row : row + 1].clone()
        layers.append(new)
    single = copy.copy(cache)
    single.layers = layers
    return single


class NotBatchable(ValueError):
    """The answers cannot be stacked into one batch; nothing was changed, each can be decoded
    alone as it is."""


def _check_batchable(rows: Sequence[_Row]) -> None:
    """NotBatchable unless the rows' caches can be stacked (one model, batch-1 prefilled caches
    of the kinds :func:`_stack` knows)."""
    model = rows[0].gen.model
    for r in rows:
        cache = r.gen._cache
        if r.gen.model is not model:
            raise NotBatchable("rows of different models")
        if cache is None or cache_kind(cache) == "opaque":
            raise NotBatchable("a row's cache is of a kind that cannot be stacked")
        held = _attention_length(cache)
        if held is not None and held != len(r.prompt.ids):
            raise NotBatchable(f"a cache holds {held} tokens, its context {len(r.prompt.ids)}")


def decode_together(requests: Sequence[tuple[Any, Any, torch.Tensor]]) -> list[tuple[list, bool]]:
    """Greedy answers of prefilled generators, decoded as one batch (see the module docstring).

    ``requests``: (generator, prompt, logits of the prompt's last token) after the generator's
    prefill, its cache holding exactly the prompt. Returns (generated ids, finished) per request;
    each generator's cache then holds its prompt and its generated ids but the last, as after
    decoding alone. Raises :class:`NotBatchable` before touching anything when the caches
    cannot be stacked; after any other exception the caches are in an unknown state."""
    rows = [_Row(gen, prompt, [int(torch.argmax(logits))]) for gen, prompt, logits in requests]
    live = [i for i, r in enumerate(rows) if not r.done()]  # the others need no forward
    if live:
        _decode_live([rows[i] for i in live])
    return [(r.generated, r.finished) for r in rows]


def _decode_live(rows: list[_Row]) -> None:
    """The token loop of rows that each need at least one more forward."""
    _check_batchable(rows)
    gen0 = rows[0].gen
    device = gen0.device
    lengths = [len(r.prompt.ids) for r in rows]
    width = max(lengths)
    pads = [width - n for n in lengths]
    room = max(r.gen.max_new_tokens for r in rows)
    cache = _stack([r.gen._cache for r in rows], pads, room)
    for r in rows:  # the batch cache is the only copy now: no row's state is held twice
        r.gen._cache = None
    # Which cached positions each row attends to (False: padding), with room for the tokens to
    # come. Given as the 4-D boolean mask the attention takes, which the model uses as it is:
    # building one from a 2-D padding mask at every step would cost more than the step's matmuls.
    allowed = torch.ones(len(rows), 1, 1, width + room, dtype=torch.bool, device=device)
    columns = torch.arange(width, device=device)[None, :]
    allowed[:, 0, 0, :width] = columns >= torch.tensor(pads, device=device)[:, None]
    mrope = torch.tensor([next_mrope_position(r.prompt) for r in rows], device=device)
    plain = torch.tensor(lengths, device=device)
    fed, held = 0, width  # tokens fed to every live row (they started together); cache length
    while rows:
        tokens = torch.tensor([[r.generated[-1]] for r in rows], device=device)
        step = torch.stack([plain + fed, mrope + fed, mrope + fed, mrope + fed]).view(4, -1, 1)
        out = gen0.model(
            input_ids=tokens,
            position_ids=step,
            attention_mask=allowed[..., : held + 1],
            cache=cache,
            use_cache=True,
        )
        fed, held = fed + 1, held + 1
        for r, tok in zip(rows, out.logits[:, -1].argmax(-1).tolist(), strict=True):
            r.generated.append(int(tok))
        keep = [j for j, r in enumerate(rows) if not rows[j].done()]
        if len(keep) == len(rows):
            continue
        for j, r in enumerate(rows):
            if j not in keep:
                r.gen._cache = _take_row(cache, j, pads[j])
        if not keep:
            return
        # Drop the finished rows, and the padding columns no remaining row needs.
        start = min(pads[j] for j in keep)
        _select(cache, keep, start)
        allowed, held = allowed[keep, :, :, start:], held - start
        pads = [pads[j] - start for j in keep]
        rows = [rows[j] for j in keep]
        index = torch.tensor(keep, device=device)
        mrope, plain = mrope[index], plain[index]


# -- gathering (episode threads and the batcher thread) -----------------------------------------


@dataclass(slots=True)
class _Request:
    """An answer waiting to be decoded, and where its result goes."""

    gen: Any
    prompt: Any
    logits: torch.Tensor
    done: threading.Event = field(default_factory=threading.Event)
    result: tuple[list[int], bool, int] | None = None
    error: BaseException | None = None
    cancelled: bool = False  # its episode stopped waiting (a time limit)


_STOP = object()


class DecodeBatcher:
    """Decodes the answers of one model's episodes in this process together (module docstring).

    :meth:`enter` is called by each episode's generator when the episode starts, :meth:`decode`
    in the episode's thread after each prefill; a thread of the batcher's own runs the batches.
    :meth:`stop` ends that thread (the answers still queued get an error); a later
    :meth:`decode` starts a new one.
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
        self._last_decode_s = 0.0  # wall time of the latest batch's decode
        self._start_fresh()

    def _start_fresh(self) -> None:
        """No thread yet (also after a fork: the parent's thread does not exist here)."""
        self._pid = os.getpid()
        self._queue: queue.Queue[Any] = queue.Queue()
        self._thread: threading.Thread | None = None
        self._stopping = False

    # -- episode side ----------------------------------------------------------------------
    def decode(self, gen: Any, prompt: Any, logits: torch.Tensor) -> tuple[list[int], bool, int]:
        """(generated ids, finished, rows decoded together) for a prefilled generator, whose
        cache afterwards holds what :meth:`PrefixCachedGenerator._decode` would leave."""
        others = self._arrive(gen)
        first = int(torch.argmax(logits))
        needs_forward = first not in gen.eos_ids and gen.max_new_tokens > 1
        if not needs_forward or (gen.batch_mode == "auto" and others == 0):
            generated, finished = gen._decode(prompt, logits)
            self._seen(gen)
            return generated, finished, 1
        request = _Request(gen, prompt, logits)
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
        wait = max(self.wait_s, min(self._last_decode_s, _LONGEST_WAIT_S))
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
        """Decode ``batch`` together; row by row if that fails."""
        t0 = time.perf_counter()
        with torch.inference_mode():
            try:
                answers = decode_together([(r.gen, r.prompt, r.logits) for r in batch])
            except NotBatchable as exc:
                log.info("decoding %d answers one by one: %s", len(batch), exc)
                for r in batch:
                    self._alone(r, fresh=False)
            except Exception as exc:  # noqa: BLE001 - each row is retried alone below
                log.warning(
                    "a batch of %d answers failed (%s: %s); decoding them one by one",
                    len(batch),
                    type(exc).__name__,
                    exc,
                )
                for r in batch:
                    self._alone(r, fresh=True)
            else:
                for r, (generated, finished) in zip(batch, answers, strict=True):
                    r.result = (generated, finished, len(batch))
        decode_s = time.perf_counter() - t0
        self._last_decode_s = decode_s
        with self._lock:
            s = self._stats
            self._stats = BatchStats(s.batches + 1, s.rows + len(batch), max(s.largest, len(batch)))
        steps = max((len(r.result[0]) for r in batch if r.result), default=0)
        _log_batch(len(batch), steps, decode_s)
        for r in batch:
            r.done.set()

    @staticmethod
    def _alone(r: _Request, fresh: bool) -> None:
        """Decode one answer by itself: from its prefilled cache, or (``fresh``, after a failed
        batch left the cache in an unknown state) from a new prefill. An error here is this
        answer's only."""
        try:
            logits = r.logits
            if fresh:
                r.gen.drop_cache()
                logits, _reused = r.gen._prefill(r.prompt)
            generated, finished = r.gen._decode(r.prompt, logits)
            r.result = (generated, finished, 1)
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


def _log_batch(rows: int, steps: int, decode_s: float) -> None:
    """One line of :func:`record_batches`' file, when one is set."""
    if _BATCH_LOG is None:
        return
    line = {"pid": os.getpid(), "rows": rows, "steps": steps, "decode_s": round(decode_s, 6)}
    with _BATCH_LOG.open("a", encoding="utf-8") as f:
        f.write(json.dumps(line) + "\n")
