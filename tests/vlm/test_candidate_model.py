"""Candidate mode with torch (tiny random-weight models, CPU): the pointer's tokens are the
export's, its picks are listed valid actions, save/load and resumed training are exact, and a few
updates learn a rule read from the listed lines well enough to beat the marginal baseline on
held-out cases."""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, replace

import msgspec
import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")

from packlab.core.errors import ConfigError
from packlab.datagen.generator import generate_cases
from packlab.policies.candidates import ProposerConfig, propose
from packlab.policies.listed import ListedTeacher
from packlab.policies.provenance import file_sha256
from packlab.policies.registry import make_policy
from packlab.sim.episode import run_episode
from packlab.vlm.candidate.collect import Labeller
from packlab.vlm.candidate.compose import export_chat_jsonl
from packlab.vlm.candidate.evaluate import Heldout, heldout_metrics
from packlab.vlm.candidate.files import HEAD_FILE
from packlab.vlm.candidate.pointer import PointerModel, collate, encode
from packlab.vlm.candidate.policy import IN_MEMORY, CandidateVLMPolicy
from packlab.vlm.candidate.saved import load_pointer, save_pointer
from packlab.vlm.candidate.scoring import PromptSettings, score_listed
from packlab.vlm.candidate.states import append_states, listed_of, observation_of
from packlab.vlm.candidate.train import (
    CHECKPOINT,
    LOG,
    PointerTrainConfig,
    is_heldout,
    load_encoded,
    train_pointer,
)
from packlab.vlm.model.checkpoint import save_model
from packlab.vlm.model.tiny import build_tiny_model
from packlab.vlm.prompt.compact import candidate_line
from packlab.vlm.prompt.render import PROMPT_VERSION, action_text

# One torch thread for the module (tests/vlm/conftest.py).
pytestmark = [pytest.mark.torch, pytest.mark.usefixtures("one_torch_thread")]

PROPOSER = ProposerConfig(k=8, rule="lowest")
CARD = {"proposer": asdict(PROPOSER), "instructions": "short", "prompt_version": PROMPT_VERSION}
TINY = "tiny:qwen3_vl:tiny"


def _labelled(cases, teacher: str = "sdf"):
    """States of the teacher's own rollouts (what ``collect`` writes, without worker processes)."""
    states = []
    for case in cases:
        labeller = Labeller(ListedTeacher(teacher), PROPOSER, "teacher")
        run_episode(case, labeller, seed=0, backend="geometric")
        states += labeller.states
    return states


@pytest.fixture(scope="module")
def cases():
    return generate_cases("easy", 2, 11, validate=False, domain="train") + generate_cases(
        "medium", 1, 11, validate=False, domain="train"
    )


@pytest.fixture(scope="module")
def states(cases):
    return _labelled(cases)


@pytest.fixture(scope="module")
def pointer():
    """A random-weight pointer model (tiny Qwen3-VL text stack and a random head)."""
    torch.manual_seed(0)
    return PointerModel(build_tiny_model("qwen3_vl", "tiny")).eval()


@pytest.mark.parametrize("instructions", ["short", "full"])
def test_lazy_composer_gives_the_export_tokens(pointer, states, instructions, tmp_path):
    tok = pointer.vlm.tokenizer
    out = tmp_path / "sft.jsonl"
    n = export_chat_jsonl(states, out, instructions)
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    labelled = [s for s in states if s.label >= 0]
    assert n == len(rows) == len(labelled) > 5
    for s, row in zip(labelled, rows, strict=True):
        assert (row["episode_id"], row["step_index"]) == (s.case_id, s.step)
        enc = encode(tok, s, instructions)
        text = tok.apply_chat_template(
            row["messages"][:2], tokenize=False, add_generation_prompt=True
        )
        assert enc.ids.tolist() == tok(text, add_special_tokens=False)["input_ids"]
        assert enc.label == s.label == int(row["messages"][2]["content"][0]["text"])
        lines = [candidate_line(c) for c in listed_of(s)]
        assert len(enc.ends) == len(lines) and (np.diff(enc.ends) > 0).all()
        for end, line in zip(enc.ends.tolist(), lines, strict=True):
            # ends[k] is the token that completes line k: the text up to it ends with the line
            # (digits are single tokens, so nothing of the next line is read), one token less
            # does not.
            assert tok.decode(enc.ids[: end + 1].tolist()).endswith("\n" + line)
            assert not tok.decode(enc.ids[:end].tolist()).endswith(line)


def test_padding_in_a_batch_changes_no_score(pointer, states):
    encoded = [encode(pointer.vlm.tokenizer, s, "short") for s in states]
    assert len({len(e.ids) for e in encoded}) > 1 and len({len(e.ends) for e in encoded}) > 1
    batch = collate(encoded, pointer.vlm.tokenizer.pad_token_id)
    with torch.inference_mode():
        scores = pointer.score(batch)
    for row, s in zip(scores, states, strict=True):
        alone = score_listed(pointer, observation_of(s), listed_of(s), PromptSettings("short"))
        np.testing.assert_allclose(row[: len(alone)].numpy(), alone, rtol=0, atol=1e-5)
        assert torch.isneginf(row[len(alone) :]).all()


class _Checked:
    """Plays a policy and records, per step, the proposer's listed actions and the one taken."""

    def __init__(self, policy: CandidateVLMPolicy) -> None:
        self.policy, self.name, self.seen = policy, policy.name, []

    def reset(self, case, seed: int) -> None:
        self.policy.reset(case, seed)

    def act(self, observation):
        listed = [c.action for c in propose(observation, PROPOSER)]
        action = self.policy.act(observation)
        self.seen.append((listed, action))
        return action


def test_pointer_picks_are_listed_valid_actions(pointer, cases):
    # Every step the model's own pick: the overflow rule (which may set a box aside, tested in
    # tests/policies/test_overflow.py) stays out.
    policy = CandidateVLMPolicy(IN_MEMORY, threads=None, overflow="place")
    policy.use_model(pointer, CARD)
    checked = _Checked(policy)
    steps, picks = 0, []
    for case in cases:
        checked.seen = []
        result = run_episode(case, checked, seed=0, backend="geometric")
        assert len(result.steps) == len(case.objects) == len(checked.seen)
        assert all(s.valid and s.reason == "" for s in result.steps)
        assert result.metrics.invalid_by_reason == {}
        for (listed, action), step in zip(checked.seen, result.steps, strict=True):
            assert step.action == action
            assert not listed or action in listed
        picks += [listed.index(a) for listed, a in checked.seen if listed]
        steps += len(checked.seen)
    assert policy.decisions == steps
    assert policy.fallbacks < steps
    assert len(set(picks)) > 1  # the scores read the lines: not a fixed index


def test_save_load_round_trip_and_the_vlm_policy(pointer, states, cases, tmp_path):
    path = save_pointer(pointer, tmp_path / "ptr", CARD)
    back = load_pointer(path)
    state = next(s for s in states if len(s.listed) > 2)
    obs, listed = observation_of(state), listed_of(state)
    before = score_listed(pointer, obs, listed, PromptSettings("short"))
    after = score_listed(back, obs, listed, PromptSettings("short"))
    assert before.shape == (len(listed),) and np.isfinite(before).all()
    np.testing.assert_allclose(after, before, rtol=0, atol=1e-6)

    policy = make_policy("vlm", model=str(path), runtime="torch")  # saved, not exported
    assert isinstance(policy, CandidateVLMPolicy)
    policy.reset(next(c for c in cases if c.episode_id == state.case_id), 0)
    assert policy.act(obs) == listed[int(np.argmax(before))].action  # the card's prompt

    with pytest.raises(ConfigError, match="history"):
        make_policy("vlm", model=str(path), history="full")
    plain = save_model(pointer.vlm, tmp_path / "plain")
    with pytest.raises(ConfigError, match=HEAD_FILE):
        load_pointer(plain)
    (plain / HEAD_FILE).write_bytes((path / HEAD_FILE).read_bytes())
    with pytest.raises(ConfigError, match="action_format"):
        load_pointer(plain)


def _log(run) -> list[dict[str, str]]:
    with open(run / LOG) as f:
        return [{k: v for k, v in row.items() if k != "seconds"} for row in csv.DictReader(f)]


def test_training_resumes_exactly(states, tmp_path):
    path = tmp_path / "states.jsonl"
    append_states(path, states)
    common = {"states": (str(path),), "model": TINY, "steps": 6, "batch": 4, "eval_every": 3,
              "warmup": 2, "heldout_every": 3, "threads": 1}  # fmt: skip
    whole = load_pointer(train_pointer(PointerTrainConfig(out=str(tmp_path / "a"), **common)))
    cfg = PointerTrainConfig(out=str(tmp_path / "b"), stop_after=3, **common)
    half = load_pointer(train_pointer(cfg))
    assert torch.load(tmp_path / "b" / CHECKPOINT, weights_only=False)["step"] == 3
    assert half.vlm.meta["trained_steps"] == 3
    resumed = load_pointer(train_pointer(replace(cfg, stop_after=None)))
    assert resumed.vlm.meta["trained_steps"] == 6
    card = whole.vlm.meta  # how it was made, without a machine's paths
    assert card["seed"] == 0 and card["init"] is None and card["dirty"] in (True, False, None)
    assert card["states"] == [{"path": "states.jsonl", "sha256": file_sha256(path)}]
    assert card["selection"]["n"] == 0 and "last update" in card["selection"]["rule"]
    assert (
        card["pointer_train"]["states"] == ["states.jsonl"] and "out" not in card["pointer_train"]
    )
    assert str(tmp_path) not in json.dumps(card)
    # The device it ran on (resolved, not "auto") and its precision.
    assert (card["pointer_train"]["device"], card["pointer_train"]["dtype"]) == ("cpu", "fp32")

    ref, got, mid = whole.state_dict(), resumed.state_dict(), half.state_dict()
    assert ref.keys() == got.keys()
    backbone = next(k for k in ref if "layers.0.self_attn.q_proj.weight" in k)
    head = next(k for k in ref if k.startswith("head.") and k.endswith("weight"))
    for key in (head, backbone):
        assert not torch.equal(mid[key], ref[key]), key  # updates 4-6 changed it
    for key in ref:
        torch.testing.assert_close(got[key], ref[key], rtol=0, atol=1e-6, msg=key)
    assert _log(tmp_path / "b") == _log(tmp_path / "a")  # same losses, NLLs at steps 3 and 6
    assert [(r["step"], bool(r["heldout_nll"])) for r in _log(tmp_path / "a")] == [
        ("3", True),
        ("6", True),
    ]


def _largest_gap(state):
    """The listed placement with the largest gap under it as the prompt shows it (``v``, cm),
    -1 (not trained on) when that largest value is shared."""
    gaps = [round(p.void_mm / 10) for p in state.listed]
    top = max(gaps)
    return msgspec.structs.replace(state, label=gaps.index(top) if gaps.count(top) == 1 else -1)


def test_a_few_updates_beat_the_marginal_baseline_on_heldout_cases(tmp_path):
    cases = generate_cases("medium", 60, 11, validate=False, domain="train")
    states = [_largest_gap(s) for s in _labelled(cases)]
    path = tmp_path / "states.jsonl"
    append_states(path, states)
    cfg = PointerTrainConfig(states=(str(path),), out=str(tmp_path / "run"), model=TINY,
                             steps=40, batch=16, lr=3e-3, warmup=4, eval_every=40,
                             heldout_every=3, seed=0, threads=1)  # fmt: skip
    # The trainer's starting model: the same seed builds the same weights and head.
    untrained = PointerModel(build_tiny_model("qwen3_vl", "tiny", seed=cfg.seed)).eval()
    train, held_list = load_encoded(cfg, untrained.vlm.tokenizer)
    held = Heldout.of(held_list, train)
    assert len(held.states) >= 30 and len(train) > len(held.states)
    first = heldout_metrics(untrained, held)
    model = load_pointer(train_pointer(cfg))
    last = heldout_metrics(model, held)
    assert last["marginal_nll"] == first["marginal_nll"]
    assert last["heldout_nll"] < last["marginal_nll"] - 0.3, (first, last)
    assert last["heldout_nll"] < first["heldout_nll"] - 0.3, (first, last)
    assert last["heldout_match"] > 0.45 > last["first_match"], (first, last)
    (logged,) = _log(tmp_path / "run")  # the trainer's own evaluation of the same model
    assert float(logged["heldout_nll"]) == pytest.approx(last["heldout_nll"], abs=1e-3)


def test_free_json_answer_tokens_decode_to_the_action_and_name_their_fields(pointer, states):
    s = next(s for s in states if s.label >= 0)
    enc = encode(pointer.vlm.tokenizer, s, "short", answer="json")
    text = pointer.vlm.tokenizer.decode(enc.answer_ids)
    assert text == action_text(listed_of(s)[s.label].action) + "<|im_end|>"
    a = listed_of(s)[s.label].action
    for name, value in (("object_id", a.object_id), ("x", a.x), ("y", a.y)):
        digits = [
            pointer.vlm.tokenizer.decode([t])
            for t, f in zip(enc.answer_ids, enc.answer_fields, strict=True)
            if f == name
        ]
        assert "".join(digits) == str(value)
    assert enc.answer_fields[-1] == "end"


def _split_every(states) -> int:
    """A held-out stride that holds out some of these states' cases but not all."""
    ids = {s.case_id for s in states}
    return next(n for n in range(2, 50) if 0 < sum(is_heldout(i, n) for i in ids) < len(ids))


def test_free_json_mode_trains_and_plays_without_raising(states, cases, tmp_path):
    path = tmp_path / "states.jsonl"
    append_states(path, states)
    cfg = PointerTrainConfig(
        states=(str(path),), out=str(tmp_path / "run"), model=TINY, steps=4, eval_every=2,
        batch=4, warmup=1, answer="json", heldout_every=_split_every(states),
    )  # fmt: skip
    final = train_pointer(cfg)
    with open(tmp_path / "run" / LOG) as f:
        row = list(csv.DictReader(f))[-1]
    assert {"nll_object_id", "nll_rotation", "nll_x", "nll_y"} <= set(row)
    policy = make_policy("vlm", model=str(final), runtime="torch")  # free JSON: torch only
    result = run_episode(cases[0], policy, seed=0, backend="geometric")
    assert len(result.steps) == len(cases[0].objects)  # unparsable answers are recorded, not raised
