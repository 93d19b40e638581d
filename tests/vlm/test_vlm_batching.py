"""Decoding several episodes' answers together (``packlab.vlm.infer.batching``): the same greedy
answers as alone for every tiny family (images, contexts of different lengths, rows stopping at
different steps), prefix caching kept across batched steps, a failing row that loses no other
row, a batcher that stops cleanly, and a bench whose records do not depend on batching.

All need the vlm extra (torch, transformers) and are marked ``torch``.
"""

from __future__ import annotations

import json
import threading

import pytest
from _cases import small_case
from record_helpers import without_timing

from packlab.core.types import Action, Unparsable

FAMILIES = ("qwen3_5", "qwen3_vl", "qwen2_5_vl")
pytestmark = pytest.mark.torch


def _episode(index: int, steps: int) -> list[list[dict]]:
    """The contexts of one episode's first ``steps`` steps: each a heightmap image (a colour of
    the episode's own) per turn, past answers as actions; episodes start with ``index`` past
    steps, so their contexts differ in length."""
    from PIL import Image

    from packlab.vlm.prompt.render import TurnState, render_messages

    case = small_case(3 + index)
    items = ()

    def state(t: int) -> TurnState:
        colour = (40 * index % 256, 17 * t % 256, 90)
        return TurnState(Image.new("RGB", (224, 224), colour), items, t, 9 - t)

    past = [(state(t), Action(t % 2, 0, t, 0)) for t in range(index)]
    contexts = []
    for t in range(index, index + steps):
        contexts.append(render_messages(case.container, list(past), state(t)))
        past.append((state(t), Unparsable(text=f"answer {t}", error="no JSON object found")))
    return contexts


def _generator(vlm, max_new_tokens: int, eos: int | None = None):
    from packlab.vlm.infer.generate import PrefixCachedGenerator

    gen = PrefixCachedGenerator(vlm, max_new_tokens=max_new_tokens)
    if eos is not None:  # an end token the random model does produce: rows stop early
        gen.eos_ids = gen.eos_ids | {eos}
    return gen


def _play_alone(vlm, episodes, budgets, eos) -> list[list[tuple]]:
    out = []
    for contexts, budget, end in zip(episodes, budgets, eos, strict=True):
        gen = _generator(vlm, budget, end)
        out.append([gen.generate(c).token_ids for c in contexts])
    return out


def _play_together(gens, episodes) -> tuple[list, list]:
    """Each episode in a thread of its own, step by step; (token ids, generations) per episode,
    or the exception an episode's thread raised."""
    answers: list = [None] * len(gens)
    generations: list = [[] for _ in gens]

    def play(i: int) -> None:
        try:
            for context in episodes[i]:
                generations[i].append(gens[i].generate(context))
            answers[i] = [g.token_ids for g in generations[i]]
        except Exception as exc:  # noqa: BLE001 - the test reads it
            answers[i] = exc

    threads = [threading.Thread(target=play, args=(i,)) for i in range(len(gens))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    return answers, generations


@pytest.mark.parametrize("family", FAMILIES)
def test_batched_answers_equal_answers_alone(torch, family):
    """Three episodes of different lengths, with images, decoded together step after step:
    each answer is the one its episode gets alone, rows stop at different steps (budgets and an
    end token), and every step after the first reuses its episode's cached prefix."""
    from packlab.vlm.infer.batching import DecodeBatcher
    from packlab.vlm.model.tiny import build_tiny_model

    vlm = build_tiny_model(family, "tiny")
    episodes = [_episode(i, steps=3) for i in (0, 1, 3)]
    budgets = (5, 9, 7)
    probe = _play_alone(vlm, episodes, budgets, (None, None, None))
    # Episode 1 stops at a token it produces (never as a first token: such an answer needs no
    # decode, and the batch would wait for it in vain).
    firsts = {answer[0] for answer in probe[1]}
    eos = (None, next(t for t in probe[1][0][2:] if t not in firsts), None)
    alone = _play_alone(vlm, episodes, budgets, eos)
    assert any(len(answer) < 9 for answer in alone[1])

    # A long wait: every batch waits for all three episodes, so each step is one batch.
    batcher = DecodeBatcher(max_batch=8, wait_s=30.0)
    gens = [_generator(vlm, b, e) for b, e in zip(budgets, eos, strict=True)]
    for gen in gens:
        gen.batcher, gen.batch_mode = batcher, "on"
        gen.reset()  # the episode starts: the batcher now waits for it
    together, generations = _play_together(gens, episodes)
    batcher.stop()

    assert together == alone
    assert [g.batch_rows for g in generations[0]] == [3, 3, 3]
    assert all(g.reused_tokens > 0 for gens_of in generations for g in gens_of[1:])
    assert batcher.stats().largest == 3


@pytest.mark.parametrize("family", ("qwen3_5", "qwen3_vl"))
def test_rows_leave_the_batch_with_their_own_cache(torch, family):
    """After a batched answer each generator's cache holds what answering alone leaves: its
    context and its answer but the last token (checked on the values, Qwen3.5's linear-attention
    states included), for a row that reuses a cached prefix batched with a row that starts
    fresh (Qwen3-VL prefills them as one ragged batch, Qwen3.5 row by row)."""
    from packlab.vlm.infer.batching import answer_together
    from packlab.vlm.model.tiny import build_tiny_model

    vlm = build_tiny_model(family, "tiny")
    episodes = [_episode(i, steps=2) for i in (0, 2)]
    runs = []
    with torch.inference_mode():
        for batched in (False, True):
            gens = [_generator(vlm, n) for n in (4, 7)]
            gens[0].generate(episodes[0][0])  # its first step, alone: a prefix to reuse
            prompts = [gens[0]._encode(episodes[0][1]), gens[1]._encode(episodes[1][0])]
            if batched:
                answers = [
                    (a.generated, a.finished, a.reused)
                    for a in answer_together(list(zip(gens, prompts, strict=True)))
                ]
            else:
                answers = []
                for g, prompt in zip(gens, prompts, strict=True):
                    logits, reused = g._prefill(prompt)
                    answers.append((*g._decode(prompt, logits), reused))
            runs.append((answers, [g._cache for g in gens]))
    (answers_a, caches_a), (answers_b, caches_b) = runs
    assert answers_a == answers_b
    assert answers_b[0][2] > 0 and answers_b[1][2] == 0  # one row reused its prefix, one did not
    for a, b in zip(caches_a, caches_b, strict=True):
        for la, lb in zip(a.layers, b.layers, strict=True):
            if getattr(la, "keys", None) is not None:
                assert la.keys.shape == lb.keys.shape
                torch.testing.assert_close(la.keys, lb.keys)
                torch.testing.assert_close(la.values, lb.values)
            for store in ("conv_states", "recurrent_states"):
                for k, v in getattr(la, store, {}).items():
                    if v is not None:
                        torch.testing.assert_close(v, getattr(lb, store)[k])


def test_a_failing_row_loses_no_other_row(torch, monkeypatch):
    """A batch that fails (as out of memory would) is decoded again row by row; the one row
    that fails alone raises in its own episode, the others get their answers."""
    from packlab.vlm.infer import batching
    from packlab.vlm.infer.batching import DecodeBatcher
    from packlab.vlm.model.tiny import build_tiny_model

    vlm = build_tiny_model("qwen3_vl", "tiny")
    episodes = [_episode(i, steps=1) for i in (0, 1, 2)]
    alone = _play_alone(vlm, episodes, (6, 6, 6), (None, None, None))

    def no_room(*args, **kwargs):
        raise RuntimeError("out of memory (simulated)")

    monkeypatch.setattr(batching, "_prefill_ragged", no_room)
    batcher = DecodeBatcher(wait_s=30.0)
    gens = [_generator(vlm, 6) for _ in episodes]
    for gen in gens:
        gen.batcher, gen.batch_mode = batcher, "on"
        gen.reset()

    def broken(prompt):  # this row's prefill alone fails too
        raise ValueError("this row is broken")

    gens[1]._prefill = broken
    together, _ = _play_together(gens, episodes)
    batcher.stop()
    assert together[0] == alone[0] and together[2] == alone[2]
    assert isinstance(together[1], ValueError) and "broken" in str(together[1])
    assert gens[1]._cache is None  # the next step encodes its whole context again


def test_the_batcher_stops_cleanly_and_starts_again(torch):
    """stop() ends the batcher's thread once the batch it holds is answered; a later answer
    starts a new thread; the runtime stops every batcher of the process."""
    from packlab.vlm.infer import runtime
    from packlab.vlm.infer.batching import DecodeBatcher
    from packlab.vlm.model.tiny import build_tiny_model

    vlm = build_tiny_model("qwen3_vl", "tiny")
    batcher = DecodeBatcher(wait_s=30.0)
    waiting, idle = _generator(vlm, 4), _generator(vlm, 4)
    for gen in (waiting, idle):
        gen.batcher, gen.batch_mode = batcher, "on"
        gen.reset()
    context = _episode(0, steps=1)[0]
    result: list = []
    asker = threading.Thread(target=lambda: result.append(waiting.generate(context)))
    asker.start()
    # The batcher waits for the idle episode (30 s at most); stop() ends the wait.
    for _ in range(200):
        if batcher._thread is not None and not batcher._queue.qsize():
            break
        threading.Event().wait(0.05)
    batcher.stop()
    asker.join(30)
    assert result and len(result[0].token_ids) == 4 and result[0].batch_rows == 1
    assert batcher._thread is not None and not batcher._thread.is_alive()
    assert batcher._thread not in threading.enumerate()  # (other tests' batchers may live on)

    batcher.wait_s = 0.01  # the idle episode is still active: do not wait for it
    again = waiting.generate(context)  # a new thread serves it
    assert again.token_ids == result[0].token_ids
    assert batcher._thread.is_alive()
    batcher.stop()
    assert not batcher._thread.is_alive()

    gen = _generator(vlm, 4)
    runtime.attach_batcher(gen, "on", 2)
    gen.reset()
    gen.generate(context)
    runtime.stop_batchers()
    assert batcher._thread not in threading.enumerate()  # (other tests' batchers may live on)


def test_ragged_attention_leaves_answers_alone_unchanged(torch):
    """Enabling ragged batches wraps the model's attention; a forward outside a batch runs the
    model's own implementation, so an episode's answers alone are the same before and after."""
    from packlab.vlm.infer.batching import _RAGGED_PREFIX, enable_ragged_batches
    from packlab.vlm.model.tiny import build_tiny_model

    vlm = build_tiny_model("qwen3_vl", "tiny")
    episode = _episode(1, steps=3)
    before = _play_alone(vlm, [episode], (6,), (None,))
    assert enable_ragged_batches(vlm.model)
    assert vlm.model.config.text_config._attn_implementation == _RAGGED_PREFIX + "sdpa"
    assert vlm.model.config.vision_config._attn_implementation == "sdpa"  # the tower's own
    assert enable_ragged_batches(vlm.model)  # idempotent
    assert _play_alone(vlm, [episode], (6,), (None,)) == before


def test_a_model_without_a_registered_attention_is_answered_row_by_row(torch):
    """``eager`` attention has no ragged form: the batcher answers each prompt alone, with the
    answers it would give alone."""
    from packlab.vlm.infer.batching import DecodeBatcher
    from packlab.vlm.model.tiny import build_tiny_model

    vlm = build_tiny_model("qwen3_vl", "tiny")
    vlm.model.config.text_config._attn_implementation = "eager"
    episodes = [_episode(i, steps=2) for i in (0, 2)]
    alone = _play_alone(vlm, episodes, (5, 5), (None, None))
    batcher = DecodeBatcher(max_batch=8, wait_s=30.0)
    gens = [_generator(vlm, 5) for _ in episodes]
    for gen in gens:
        gen.batcher, gen.batch_mode = batcher, "on"
        gen.reset()
    together, generations = _play_together(gens, episodes)
    batcher.stop()
    assert together == alone
    assert {g.batch_rows for gens_of in generations for g in gens_of} == {1}
    assert vlm.model.config.text_config._attn_implementation == "eager"


def test_auto_decodes_alone_when_one_episode_asks(torch):
    """batch=auto: a single episode in the process decodes in its own thread, no batcher."""
    from packlab.policies import make_policy
    from packlab.sim.episode import run_episode

    policy = make_policy("vlm", model="tiny:qwen3_vl:tiny", max_new_tokens=4)
    assert policy.batch == "auto"
    run_episode(small_case(), policy, seed=0, backend="geometric")
    assert {s["batch_rows"] for s in policy.step_log} == {1}
    assert policy.generator.batcher.stats().batches == 0
    assert policy.config()["batch"] == "auto"


def test_bad_batch_options_are_config_errors(torch):
    from packlab.cli.policy_options import check_policy_args
    from packlab.core.errors import ConfigError
    from packlab.policies import make_policy
    from packlab.vlm.infer import batching, policy

    # The policy module lists them without importing torch; they must agree.
    assert (policy.BATCH_MODES, policy.DEFAULT_MAX_BATCH) == (
        batching.MODES,
        batching.DEFAULT_MAX_BATCH,
    )

    for key, value in (("batch", "always"), ("max_batch", 0)):
        with pytest.raises(ConfigError, match=key):
            make_policy("vlm", model="tiny:qwen3_vl:tiny", **{key: value})
        with pytest.raises(ConfigError, match=key):
            check_policy_args([("vlm", key, value)])


def test_bench_records_do_not_depend_on_batching(torch, tmp_path):
    """``packlab bench --concurrency 2`` with batching gives the records of concurrency 1."""
    from packlab.bench.records import read_record_file, record_key
    from packlab.cases.write import save_cases
    from packlab.cli.main import main
    from packlab.core.records import to_builtins
    from packlab.vlm.infer import batching

    cases = save_cases([small_case(s) for s in (3, 4, 5)], tmp_path / "cases.jsonl")
    log = tmp_path / "batches.jsonl"
    batching.record_batches(log)  # the forked worker inherits it
    records = {}
    try:
        for n, batch in (("1", "off"), ("2", "on")):
            out = tmp_path / f"n{n}"
            argv = ["bench", "--cases", str(cases), "--policies", "vlm", "--seeds", "0"]
            argv += ["--backend", "geometric", "--workers", "1", "--concurrency", n]
            argv += ["--policy-arg", "vlm:model=tiny:qwen3_vl:tiny"]
            argv += ["--policy-arg", "vlm:max_new_tokens=6", "--policy-arg", f"vlm:batch={batch}"]
            argv += ["--out", str(out), "--no-progress", "--no-figures", "--no-html"]
            assert main(argv) == 0
            found = read_record_file(out / "episodes.jsonl").records
            records[n] = {record_key(r): without_timing(to_builtins(r)) for r in found}
    finally:
        batching.record_batches(None)
    assert len(records["1"]) == 3 and records["2"] == records["1"]
    batches = [json.loads(line) for line in log.read_text().splitlines()]
    assert batches and sum(b["rows"] for b in batches) == sum(
        len(r["steps"]) for r in records["2"].values()
    )
