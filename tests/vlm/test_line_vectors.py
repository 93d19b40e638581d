"""The pointer head that reads line vectors: vectors reach the scores, survive save/load, and a
card written before them loads a plain linear head."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")

from packlab.datagen.generator import generate_cases
from packlab.policies.candidates import ProposerConfig
from packlab.policies.line_vector import LINE_VECTOR_SIZE, line_vectors
from packlab.policies.listed import ListedTeacher
from packlab.sim.episode import run_episode
from packlab.vlm.candidate.collect import Labeller
from packlab.vlm.candidate.pointer import LineHead, PointerModel, collate, encode
from packlab.vlm.candidate.saved import load_pointer, save_pointer
from packlab.vlm.candidate.states import listed_of, observation_of
from packlab.vlm.model.tiny import build_tiny_model
from packlab.vlm.prompt.render import PROMPT_VERSION

pytestmark = pytest.mark.torch

PROPOSER = ProposerConfig(k=16)
CARD = {"proposer": asdict(PROPOSER), "instructions": "short", "prompt_version": PROMPT_VERSION}


@pytest.fixture(scope="module")
def states():
    torch.set_num_threads(1)
    case = generate_cases("medium", 1, 12, validate=False, domain="train")[0]
    labeller = Labeller(ListedTeacher("plan"), PROPOSER, "teacher")
    run_episode(case, labeller, seed=0, backend="geometric")
    return [s for s in labeller.states if len(s.listed) > 2]


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return PointerModel(build_tiny_model("qwen3_vl", "tiny"), map="image", lines=True).eval()


def _batch(model, states, lines=True):
    tok = model.vlm.tokenizer
    encoded = [encode(tok, s, "short", map="image", lines=lines) for s in states]
    return encoded, collate(encoded, tok.pad_token_id)


def test_encoded_vectors_are_the_line_vectors(model, states):
    encoded, batch = _batch(model, states[:3])
    for e, s in zip(encoded, states[:3]):
        assert np.array_equal(e.vectors, line_vectors(observation_of(s), listed_of(s)))
    k = max(len(s.listed) for s in states[:3])
    assert batch["vectors"].shape == (3, k, LINE_VECTOR_SIZE)
    assert "vectors" not in _batch(model, states[:3], lines=False)[1]


def test_vectors_reach_the_scores(model, states):
    _, batch = _batch(model, states[:2])
    with torch.no_grad():
        before = model.score(batch)
        changed = dict(batch, vectors=batch["vectors"] + 0.5)
        after = model.score(changed)
    valid = batch["valid"]
    assert torch.isfinite(before[valid]).all()
    assert not torch.allclose(before[valid], after[valid])
    assert torch.isinf(before[~valid]).all()


def test_line_head_round_trips_and_old_cards_load_a_linear_head(model, states, tmp_path):
    save_pointer(model, tmp_path / "m", {**CARD, "map": "image", "line_vectors": True})
    back = load_pointer(tmp_path / "m")
    assert back.lines and isinstance(back.head, LineHead)
    _, batch = _batch(model, states[:2])
    with torch.no_grad():
        torch.testing.assert_close(back.score(batch), model.score(batch))
    plain = PointerModel(build_tiny_model("qwen3_vl", "tiny"), map="image").eval()
    save_pointer(plain, tmp_path / "old", {**CARD, "map": "image"})  # no line_vectors field
    old = load_pointer(tmp_path / "old")
    assert not old.lines and isinstance(old.head, torch.nn.Linear)


def test_plan_teacher_states_carry_the_added_pick(states):
    added = [s for s in states if s.teacher_added]
    assert all(s.label == len(s.listed) - 1 for s in added)
    assert all(len(s.listed) <= PROPOSER.k + 1 for s in states)


def test_blank_image_policy_shows_an_empty_container_only(model, states, tmp_path):
    from packlab.core.errors import ConfigError
    from packlab.policies.registry import make_policy
    from packlab.vlm.candidate.scoring import score_listed

    save_pointer(model, tmp_path / "m", {**CARD, "map": "image", "line_vectors": True})
    seen, blank = (
        make_policy("vlm", model=str(tmp_path / "m"), blank_image=b, runtime="torch")
        for b in (False, True)
    )
    state = next(s for s in states if observation_of(s).heightmap.any())
    obs, listed = observation_of(state), listed_of(state)
    for p in (seen, blank):
        p.load()
    assert blank._settings.blank_map and not seen._settings.blank_map
    a = score_listed(seen._model, obs, listed, seen._settings)
    b = score_listed(blank._model, obs, listed, blank._settings)
    assert not np.allclose(a, b)  # the image carried the heightmap; blanked, the scores move
    with pytest.raises(ConfigError, match="blank_image = 'yes'"):
        make_policy("vlm", model=str(tmp_path / "m"), blank_image="yes")
