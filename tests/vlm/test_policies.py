"""The ``vlm`` inference policy: closed-loop episodes with a tiny model, prefix-cache reuse that
gives the same greedy answers as re-encoding, registry and pickling.

Tests that run a model need the vlm extra (torch, transformers) and are marked ``torch``; the
registry tests run in the core install.
"""

from __future__ import annotations

import itertools
import json
import pickle
import subprocess
import sys

import numpy as np
import pytest
from _cases import small_case

from packlab.core.errors import ConfigError
from packlab.core.types import Action, Unparsable
from packlab.policies import available_policies, make_policy
from packlab.sim.episode import INVALID_REASONS, run_episode
from packlab.vlm.prompt.compact import parse_choice
from packlab.vlm.prompt.render import PROMPT_VERSION, action_text

FAMILIES = ("qwen3_5", "qwen3_vl", "qwen2_5_vl")


def _records(result):
    return [s.to_record()["action"] for s in result.steps]


def _check_steps(result, case):
    assert len(result.steps) == len(case.objects)
    for s in result.steps:
        if s.valid:
            assert isinstance(s.action, Action) and s.reason == ""
        else:
            assert s.reason in INVALID_REASONS
            if isinstance(s.action, Unparsable):
                assert s.reason == "unparsable" and s.action.error
    m = result.metrics
    assert m.n_objects == len(case.objects)
    assert sum(m.invalid_by_reason.values()) == sum(not s.valid for s in result.steps)


# -- registry and construction (core install) ----------------------------------------------------
def test_policies_are_registered():
    names = available_policies()
    assert {"vlm", "vlm-small", "endpoint"} <= set(names)


def test_policy_module_does_not_import_torch():
    code = (
        "import sys, packlab.policies as p; p.make_policy('vlm', model='tiny:qwen3_5:tiny');"
        "p.make_policy('endpoint', base_url='http://127.0.0.1:9/v1');"
        "assert 'torch' not in sys.modules and 'transformers' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_bad_configuration_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="not a checkpoint directory"):
        make_policy("vlm", model=str(tmp_path))
    with pytest.raises(ConfigError, match="history"):
        make_policy("vlm", history="everything")
    with pytest.raises(ConfigError, match="max_new_tokens"):
        make_policy("vlm", max_new_tokens=0)


def test_vlm_small_without_shipped_checkpoint_says_how_to_reproduce(monkeypatch, tmp_path):
    import packlab.vlm.infer.policy as vp

    monkeypatch.setattr(vp, "SHIPPED_MODEL_DIR", tmp_path / "vlm-small")
    with pytest.raises(ConfigError, match="packlab train candidate"):
        make_policy("vlm-small")


def test_unpicklable_parts_are_not_pickled():
    policy = make_policy("vlm", model="tiny:qwen3_5:tiny", max_new_tokens=4)
    clone = pickle.loads(pickle.dumps(policy))
    assert clone.model_spec == "tiny:qwen3_5:tiny" and clone.generator is None


# -- episodes with a tiny model -------------------------------------------------------------------
@pytest.mark.torch
def test_vlm_policy_completes_an_episode(torch):
    case = small_case()
    policy = make_policy("vlm", model="tiny:qwen3_5:tiny", max_new_tokens=8)
    result = run_episode(case, policy, seed=0, backend="geometric")
    _check_steps(result, case)
    # A random-weight model answers garbage: recorded as unparsable, the episode went on.
    assert result.metrics.invalid_by_reason.get("unparsable", 0) >= 1
    assert len(policy.step_log) == len(case.objects)
    assert policy.resolved["options"] == {"history": "full", "image": "heightmap"}
    # Every step after the first reused the cached conversation prefix.
    log = policy.step_log
    assert log[0]["reused_tokens"] == 0
    assert all(0 < s["reused_tokens"] < s["prompt_tokens"] for s in log[1:])
    assert all(a["prompt_tokens"] < b["prompt_tokens"] for a, b in itertools.pairwise(log))
    # A second episode on the same policy starts from a clean cache.
    again = run_episode(case, policy, seed=0, backend="geometric")
    assert _records(again) == _records(result) and policy.step_log[0]["reused_tokens"] == 0


@pytest.mark.torch
@pytest.mark.parametrize("family", FAMILIES)
def test_cached_and_uncached_generations_are_identical(torch, family):
    case = small_case(5)
    runs = {}
    for reuse in (True, False):
        policy = make_policy(
            "vlm", model=f"tiny:{family}:tiny", max_new_tokens=6, reuse_cache=reuse
        )
        result = run_episode(case, policy, seed=1, backend="geometric")
        runs[reuse] = (_records(result), policy.step_log)
    assert runs[True][0] == runs[False][0]
    assert [s["new_tokens"] for s in runs[True][1]] == [s["new_tokens"] for s in runs[False][1]]
    assert sum(s["reused_tokens"] for s in runs[True][1]) > 0
    assert sum(s["reused_tokens"] for s in runs[False][1]) == 0


@pytest.mark.torch
@pytest.mark.parametrize("family", FAMILIES)
def test_first_step_matches_model_generate(torch, family):
    """The hand-written greedy loop (explicit M-RoPE positions) is what ``generate`` computes."""
    from packlab.sim.episode import Episode
    from packlab.vlm.data.encoding import collate, encode
    from packlab.vlm.infer.generate import PrefixCachedGenerator
    from packlab.vlm.model.tiny import build_tiny_model
    from packlab.vlm.prompt.context import ContextRenderer

    vlm = build_tiny_model(family, "tiny")
    case = small_case()
    episode = Episode("geometric")
    obs = episode.reset(case, 0)
    episode.step(Action(0, 0, 0, 0))
    messages = ContextRenderer().messages(episode.observe())  # one past step: two images
    gen = PrefixCachedGenerator(vlm, max_new_tokens=10, reuse_prefix=False).generate(messages)
    enc = encode(messages, vlm.tokenizer, vlm.image_processor)
    batch = collate([enc], vlm.tokenizer.pad_token_id, padding_side="left")
    with torch.no_grad():
        out = vlm.model.generate(**batch, max_new_tokens=10, do_sample=False)
    assert list(gen.token_ids) == out[0, enc.length :].tolist()
    assert obs.step_index == 0


class _ScriptedLogits:
    """Runs the real model (so the cache is really filled) but forces the chosen tokens to a
    scripted answer per step; records the real logits each choice was made from."""

    def __init__(self, model, answers, tokenizer, torch):
        self._model, self._torch = model, torch
        end = tokenizer.convert_tokens_to_ids("<|im_end|>")
        self.answers = [
            tokenizer(a, add_special_tokens=False)["input_ids"] + [end] for a in answers
        ]
        self.step, self.cursor = -1, 0
        self.used: list = []  # (step, cursor, real logits)

    def __getattr__(self, name):
        return getattr(self._model, name)

    def __call__(self, **kwargs):
        out = self._model(**kwargs)
        prefill = "logits_to_keep" in kwargs
        if prefill:
            if not (self.used and self.used[-1][1] == 0 and self.used[-1][0] == self.step):
                self.step += 1
            else:
                self.used.pop()  # an earlier chunk of the same prefill
            self.cursor = 0
        else:
            self.cursor += 1
        self.used.append((self.step, self.cursor, out.logits[0, -1].clone()))
        answer = self.answers[self.step % len(self.answers)]
        forced = self._torch.full_like(out.logits[0, -1], -1e4)
        forced[answer[min(self.cursor, len(answer) - 1)]] = 0.0
        out.logits[0, -1] = forced
        return out


@pytest.mark.torch
@pytest.mark.parametrize("family", ("qwen3_5", "qwen3_vl"))
def test_answers_that_parse_are_reused_whole_and_match_uncached(torch, family):
    """With answers that re-tokenise as generated, the cache holds the whole previous context
    plus the answer, and the real logits equal those of a full re-encode."""
    answers = [
        action_text(Action(0, 0, 0, 0)),
        "I would put it in the corner.",
        action_text(Action(1, 1, 0, 0)),
    ]
    case = small_case()
    runs = {}
    for reuse in (True, False):
        policy = make_policy(
            "vlm", model=f"tiny:{family}:tiny", max_new_tokens=40, reuse_cache=reuse
        )
        policy.load()
        gen = policy.generator
        gen.model = _ScriptedLogits(gen.model, answers, gen.tokenizer, torch)
        result = run_episode(case, policy, seed=0, backend="geometric")
        _check_steps(result, case)
        runs[reuse] = (result, policy.step_log, gen.model.used)
    result, log, used = runs[True]
    assert isinstance(result.steps[0].action, Action) and result.steps[0].valid
    assert isinstance(result.steps[1].action, Unparsable)
    assert result.steps[1].action.text == answers[1]
    for prev, cur in itertools.pairwise(log):
        assert cur["reused_tokens"] == prev["prompt_tokens"] + prev["new_tokens"] - 1
    assert _records(result) == _records(runs[False][0])
    ref = runs[False][2]
    assert [(s, c) for s, c, _ in used] == [(s, c) for s, c, _ in ref]
    worst = max(float((a - b).abs().max()) for (_, _, a), (_, _, b) in zip(used, ref))
    assert worst < 1e-4, worst


@pytest.mark.torch
def test_a_changed_image_is_never_taken_from_the_cache(torch):
    """Image placeholder tokens do not tell images apart: the cache must compare the pixels."""
    from PIL import Image

    from packlab.vlm.data.encoding import encode
    from packlab.vlm.infer.generate import PrefixCachedGenerator
    from packlab.vlm.model.tiny import build_tiny_model
    from packlab.vlm.prompt.render import TurnState, render_messages

    vlm = build_tiny_model("qwen3_vl", "tiny")
    container = small_case().container
    obs_items = ()
    first = TurnState(Image.new("RGB", (224, 224), (200, 0, 0)), obs_items, 0, 3)
    other = TurnState(Image.new("RGB", (224, 224), (0, 0, 200)), obs_items, 0, 3)
    current = TurnState(Image.new("RGB", (224, 224), (0, 200, 0)), obs_items, 1, 2)
    a = render_messages(container, [(first, Action(0, 0, 0, 0))], current)
    b = render_messages(container, [(other, Action(0, 0, 0, 0))], current)
    cached = PrefixCachedGenerator(vlm, max_new_tokens=5)
    cached.generate(a)
    g = cached.generate(b)
    fresh = PrefixCachedGenerator(vlm, max_new_tokens=5, reuse_prefix=False).generate(b)
    enc_a = encode(a, vlm.tokenizer, vlm.image_processor)
    enc_b = encode(b, vlm.tokenizer, vlm.image_processor)
    assert enc_a.input_ids.tolist() == enc_b.input_ids.tolist()  # same tokens, other pixels
    first_image = enc_b.mm_token_type_ids.tolist().index(1)
    assert g.reused_tokens == first_image  # the shared text before the changed image, no more
    assert g.token_ids == fresh.token_ids


@pytest.mark.torch
def test_memo_image_processor_matches_batched_processing(torch):
    from PIL import Image

    from packlab.vlm.infer.generate import MemoImageProcessor
    from packlab.vlm.model.checkpoint import image_processor_for

    inner = image_processor_for("qwen3_5")
    ims = [Image.new("RGB", (224, 224), c) for c in ((1, 2, 3), (50, 60, 70), (1, 2, 3))]
    ims.append(Image.new("RGB", (96, 160), (9, 9, 9)))
    ref = inner(images=ims, return_tensors="pt")
    memo = MemoImageProcessor(inner)
    out = memo(images=ims, return_tensors="pt")
    assert torch.equal(out["pixel_values"], ref["pixel_values"])
    assert torch.equal(out["image_grid_thw"], ref["image_grid_thw"])
    assert memo.last_keys[0] == memo.last_keys[2] != memo.last_keys[1]
    assert memo.merge_size == inner.merge_size


@pytest.mark.torch
def test_history_longer_than_max_length_drops_oldest_steps(torch):
    case = small_case()
    policy = make_policy("vlm", model="tiny:qwen3_5:tiny", max_new_tokens=4, max_length=700)
    result = run_episode(case, policy, seed=0, backend="geometric")
    _check_steps(result, case)
    assert any(s["dropped_steps"] > 0 for s in policy.step_log)
    assert all(s["prompt_tokens"] <= 700 for s in policy.step_log)


@pytest.mark.torch
@pytest.mark.parametrize(
    "options",
    [{"history": "current_only", "image": "blank"}, {"history": "no_actions", "image": "none"}],
)
def test_ablation_options_run(torch, options):
    case = small_case()
    runs = []
    for reuse in (True, False):
        policy = make_policy(
            "vlm", model="tiny:qwen3_vl:tiny", max_new_tokens=4, reuse_cache=reuse, **options
        )
        runs.append(_records(run_episode(case, policy, seed=0, backend="geometric")))
        assert policy.resolved["options"] == options
    assert runs[0] == runs[1]


@pytest.mark.torch
def test_loaded_policy_pickles_as_configuration(torch):
    policy = make_policy("vlm", model="tiny:qwen3_5:tiny", max_new_tokens=4)
    case = small_case()
    first = _records(run_episode(case, policy, seed=0, backend="geometric"))
    blob = pickle.dumps(policy)
    assert len(blob) < 10_000  # configuration only, no weights
    clone = pickle.loads(blob)
    assert _records(run_episode(case, clone, seed=0, backend="geometric")) == first


@pytest.mark.torch
def test_policies_of_one_model_share_its_weights_in_a_process(torch):
    """The bench runner builds a policy per episode: the weights must load once per process."""
    a = make_policy("vlm", model="tiny:qwen3_vl:tiny", max_new_tokens=4)
    b = make_policy("vlm", model="tiny:qwen3_vl:tiny", max_new_tokens=4, reuse_cache=False)
    other = make_policy("vlm", model="tiny:qwen3_vl:tiny", model_seed=1, max_new_tokens=4)
    for p in (a, b, other):
        p.load()
    assert a.generator.vlm is b.generator.vlm is not other.generator.vlm
    assert a.generator is not b.generator  # per-episode state stays per policy


@pytest.mark.torch
def test_checkpoint_directory_and_its_training_options(torch, tmp_path):
    from packlab.vlm.model.checkpoint import save_model
    from packlab.vlm.model.tiny import build_tiny_model

    vlm = build_tiny_model("qwen3_5", "tiny", seed=2)
    save_model(
        vlm,
        tmp_path / "ckpt",
        extra_meta={
            "sft_config": {"history": "no_actions", "image": "heightmap", "max_length": 4096}
        },
    )
    policy = make_policy("vlm", model=str(tmp_path / "ckpt"), max_new_tokens=4)
    policy.load()
    assert policy.resolved["options"] == {"history": "no_actions", "image": "heightmap"}
    assert policy.resolved["max_length"] == 4096
    tiny = make_policy(
        "vlm", model="tiny:qwen3_5:tiny", model_seed=2, max_new_tokens=4, history="no_actions"
    )
    case = small_case()
    assert _records(run_episode(case, policy, 0, "geometric")) == _records(
        run_episode(case, tiny, 0, "geometric")
    )


@pytest.mark.torch
def test_endpoint_against_the_tiny_model_server_matches_the_local_policy(torch):
    """The endpoint policy, through a local OpenAI-compatible server of the same tiny model,
    takes the same actions as the local policy (images survive the PNG data URL round trip)."""
    from packlab.vlm.serve.model_answers import model_answer_fn
    from packlab.vlm.serve.server import serve

    case = small_case()
    local = make_policy("vlm", model="tiny:qwen3_vl:tiny", max_new_tokens=6)
    expected = _records(run_episode(case, local, seed=0, backend="geometric"))
    with serve(model_answer_fn("tiny:qwen3_vl:tiny", max_new_tokens=6)) as server:
        remote = make_policy(
            "endpoint", base_url=server.base_url, model="tiny", max_tokens=6, timeout_s=60
        )
        got = _records(run_episode(case, remote, seed=0, backend="geometric"))
    assert got == expected
    # The server encoded the same context: same token counts, reported through `usage`.
    assert [s["prompt_tokens"] for s in remote.step_log] == [
        s["prompt_tokens"] for s in local.step_log
    ]
    assert {s["finish_reason"] for s in remote.step_log} <= {"stop", "length"}


# -- candidate mode: answers are placement indices (or free JSON in the format ablation) ---------
def _stub_candidate_policy(answer: str):
    """A candidate-mode policy around no model at all: the test replaces its scorer or its
    generator (``answer`` = ``index`` or ``json``, as a checkpoint's card says)."""
    from packlab.vlm.candidate.policy import IN_MEMORY, CandidateVLMPolicy

    # overflow=place: every step is the model's answer under test (rule ``score`` may decide
    # the episode's last box itself).
    policy = CandidateVLMPolicy(IN_MEMORY, overflow="place")
    card = {"prompt_version": PROMPT_VERSION, "proposer": {"k": 8}, "instructions": "short"}
    policy.use_model(object(), meta={**card, "answer": answer})
    return policy


@pytest.mark.torch
def test_malformed_and_out_of_range_json_answers_are_counted_and_the_episode_goes_on(torch):
    case = small_case()
    answers = iter(
        [
            "I would put it on the left.",  # malformed: no action at all
            action_text(Action(7, 0, 0, 0)),  # object 7 of a 2-object buffer
            action_text(Action(0, 0, 99, 0)),  # off the 8 x 6 floor
            action_text(Action(0, 0, 0, 0)),  # fine
            '{"object_id": 0, "rotation": 0',  # cut off
            action_text(Action(0, 2, 0, 0)),  # no rotation 2
        ]
    )
    policy = _stub_candidate_policy("json")
    policy._generate = lambda model, observation, listed, settings: next(answers)
    result = run_episode(case, policy, seed=0, backend="geometric")
    _check_steps(result, case)
    assert [s.reason for s in result.steps] == [
        "unparsable",
        "bad_object_id",
        "out_of_bounds",
        "",
        "unparsable",
        "unparsable",
    ]
    assert result.metrics.invalid_by_reason == {
        "bad_object_id": 1,
        "out_of_bounds": 1,
        "unparsable": 3,
    }
    assert result.metrics.n_set_aside == 5


def _pick_third(chosen):
    """A scorer that ranks listed placement 2 (or the last, with fewer) first."""

    def score(model, observation, listed, settings):
        index = min(2, len(listed) - 1)
        chosen.append((listed, index))
        return np.eye(len(listed))[index]

    return score


@pytest.mark.torch
def test_an_index_answer_takes_exactly_the_placement_it_names(torch):
    case = small_case()
    chosen: list = []
    policy = _stub_candidate_policy("index")
    policy._score = _pick_third(chosen)
    result = run_episode(case, policy, seed=0, backend="geometric")
    assert len(chosen) + policy.fallbacks == len(result.steps) == len(case.objects)
    assert policy.fallbacks == 0 and any(index == 2 for _, index in chosen)
    for step, (listed, index) in zip(result.steps, chosen):
        assert step.action == listed[index].action == parse_choice(str(index), listed)


def _extra_score(model, observation, listed, settings):
    return np.r_[np.zeros(len(listed)), 1.0]  # the best "placement" is not listed


def _nan_scores(model, observation, listed, settings):
    return np.full(len(listed), np.nan)


@pytest.mark.torch
@pytest.mark.parametrize("scorer", [_extra_score, _nan_scores])
def test_scores_that_name_no_listed_placement_are_unparsable_steps(torch, scorer):
    case = small_case()
    policy = _stub_candidate_policy("index")
    policy._score = scorer
    result = run_episode(case, policy, seed=0, backend="geometric")
    _check_steps(result, case)
    assert result.metrics.invalid_by_reason == {"unparsable": len(case.objects)}


def test_pick_listed_takes_the_best_finite_score_and_names_what_is_wrong():
    from packlab.vlm.candidate.policy import pick_listed

    class Listed:
        def __init__(self, action):
            self.action = action

    listed = [Listed(f"a{i}") for i in range(3)]
    assert pick_listed(listed, [np.nan, 0.2, np.inf]) == "a1"  # inf is not finite, NaN ignored
    assert pick_listed(listed, [0.1, np.nan, 0.3]) == "a2"
    assert pick_listed(listed, [-5.0, -np.inf, np.nan]) == "a0"
    bad = {
        "shape (4,) for 3 listed": [0.0, 0.0, 0.0, 1.0],
        "shape (2,) for 3 listed": [0.0, 1.0],
        "shape (1, 3) for 3 listed": [[0.0, 1.0, 2.0]],
        "no finite score among 3": [np.nan, np.nan, -np.inf],
        "not numbers": ["x", "y", "z"],
    }
    for words, scores in bad.items():
        out = pick_listed(listed, scores)
        assert isinstance(out, Unparsable) and words in out.error, (words, out)


@pytest.mark.torch
def test_shipped_vlm_small_checkpoint_plays_a_bench_case():
    import packlab.vlm.infer.policy as vp
    from packlab.bench.suites import load_suite

    meta_path = vp.SHIPPED_MODEL_DIR / "packlab_model.json"
    if not meta_path.exists():
        pytest.skip("no vlm-small checkpoint in this install")
    trained_with = json.loads(meta_path.read_text()).get("prompt_version")
    if trained_with != PROMPT_VERSION:  # the policy refuses it (a ConfigError says so)
        pytest.skip(f"shipped vlm-small predates {PROMPT_VERSION} ({trained_with}): retrain it")
    pytest.importorskip("torch")
    case = next(c for c in load_suite("packlab-bench-v1") if c.difficulty == "easy")
    policy = make_policy("vlm-small")
    policy.load()
    real, seen = policy._score, []

    def score(model, observation, listed, settings):
        scores = real(model, observation, listed, settings)
        seen.append((listed, np.asarray(scores)))
        return scores

    policy._score = score
    result = run_episode(case, policy, seed=0, backend="geometric")
    assert result.policy == "vlm-small"
    assert len(result.steps) == len(case.objects) == policy.decisions
    assert policy.fallbacks == 0 and len(seen) == len(result.steps)  # every step was scored
    # The trained model's answer at every step is one finite score per listed placement; its
    # best names a listed placement (the index answer parses to the very action taken), and the
    # scores tell placements apart (a constant head would always answer 0).
    for step, (listed, scores) in zip(result.steps, seen):
        assert scores.shape == (len(listed),) and np.isfinite(scores).all()
        best = int(np.argmax(scores))
        assert step.action == listed[best].action == parse_choice(str(best), listed)
        assert len(listed) == 1 or np.ptp(scores) > 0
    assert result.metrics.invalid_by_reason == {}
