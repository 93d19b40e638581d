"""Candidate-mode options for a model whose only view of the container is the image: listed
lines without geometry (``line_fields`` = cell), the image's tokens per side (``image_tokens``)
and footprint pooling (``footprint_pool``): the lines carry no z/s/f/v, the prompt holds one pad
per visual token of the chosen grid, the pooling gathers exactly the visual tokens under each
footprint, a tiny model trains with all three and its card round-trips, export refuses it, and
the defaults encode as before."""

from __future__ import annotations

import json
import re
from dataclasses import asdict, replace

import msgspec
import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")

from packlab.core.errors import ConfigError
from packlab.core.types import Container
from packlab.policies.candidates import ProposerConfig
from packlab.policies.registry import make_policy
from packlab.vlm.candidate.compose import cell_line, line_text, state_messages
from packlab.vlm.candidate.encoding import (
    Extras,
    PromptSettings,
    footprints,
    rings,
    settings_grid,
)
from packlab.vlm.candidate.image import footprint_tokens, heightmap_image, ring_tokens
from packlab.vlm.candidate.onnx_export import export_onnx
from packlab.vlm.candidate.pointer import (
    ImageGrid,
    PointerModel,
    collate,
    encode,
    footprint_context_pool,
    footprint_pool,
)
from packlab.vlm.candidate.recipe import DaggerConfig
from packlab.vlm.candidate.saved import load_pointer, save_pointer
from packlab.vlm.candidate.scoring import score_listed
from packlab.vlm.candidate.states import append_states, listed_of, observation_of
from packlab.vlm.candidate.train import PointerTrainConfig, train_pointer
from packlab.vlm.model.tiny import build_tiny_model
from packlab.vlm.model.tokenizer import IMAGE_PAD
from packlab.vlm.prompt.compact import candidate_line

# One torch thread, and the sdf-labelled states of one medium case (tests/vlm/conftest.py).
pytestmark = [pytest.mark.torch, pytest.mark.usefixtures("one_torch_thread")]

PROPOSER = ProposerConfig(k=8, rule="lowest")
CELL_ONLY = re.compile(r"\d+: b\d+ r[01] x\d+ y\d+")


@pytest.fixture(scope="module")
def pointer():
    torch.manual_seed(0)
    return PointerModel(build_tiny_model("qwen3_vl", "tiny"), map="image", footprint=True).eval()


def _states_file(states, tmp_path):
    """``states`` written under four case ids, the first held out (by a hash of the case id:
    every third), as a trainer's states file."""
    path = tmp_path / "states.jsonl"
    append_states(path, [msgspec.structs.replace(s, case_id=f"{s.case_id}-{n % 4}")
                         for n, s in enumerate(states)])  # fmt: skip
    return path


def _places(text: str) -> list[str]:
    after = text[text.rindex("Places:") :].split("\n")[1:]
    return [line for line in after if re.match(r"\d+: b", line)]


def test_cell_lines_name_box_rotation_and_cell_only(pointer, states):
    tok = pointer.vlm.tokenizer
    state = states[0]
    listed = listed_of(state)
    user = state_messages(state, map="image", line_fields="cell")[1]["content"][-1]["text"]
    assert _places(user) == [cell_line(c) for c in listed]
    assert all(CELL_ONLY.fullmatch(line) for line in _places(user))
    assert not re.search(r" [zsfv]-?\d", user[user.rindex("Places:") :])
    full = state_messages(state, map="image")[1]["content"][-1]["text"]
    assert _places(full) == [candidate_line(c) for c in listed]  # the default is unchanged
    assert user.split("Places:")[0] == full.split("Places:")[0]  # only the lines differ
    enc = encode(tok, state, "short", map="image", extras=Extras(line_fields="cell"))
    for n, c in enumerate(listed):  # each line's first and last tokens are its own
        start, end = int(enc.starts[n]), int(enc.ends[n])
        assert tok.decode(enc.ids[start : end + 1]).strip().endswith(f"y{c.y}")
        assert tok.decode(enc.ids[start : end + 1]).strip().startswith(f"{c.index}:")
    with pytest.raises(ConfigError, match="line_fields"):
        line_text(listed[0], "some")  # type: ignore[arg-type]


@pytest.mark.parametrize("per_side", [4, 8, 12])
def test_the_prompt_holds_one_pad_per_token_of_the_chosen_grid(pointer, states, per_side):
    tok = pointer.vlm.tokenizer
    grid = settings_grid(ImageGrid.of(pointer.vlm), PromptSettings("short", image_tokens=per_side))
    assert (grid.side, grid.tokens) == (32 * per_side, per_side**2)
    enc = encode(tok, states[0], "short", map="image", grid=grid, extras=Extras(footprint=True))
    assert enc.footprint.shape == (len(listed_of(states[0])), per_side**2)
    assert int((enc.ids == tok.convert_tokens_to_ids(IMAGE_PAD)).sum()) == per_side**2
    assert enc.image is not None and enc.image.shape == (grid.side, grid.side)
    batch = collate([enc], tok.pad_token_id)
    assert batch["image_grid_thw"][0].tolist() == [1, 2 * per_side, 2 * per_side]
    scores = pointer(batch)  # the vision tower and the M-RoPE positions take the grid
    assert torch.isfinite(scores[batch["valid"]]).all()


def test_settings_of_a_card_without_the_options_are_the_defaults():
    old = PromptSettings.of({"instructions": "short", "map": "image"})
    assert (old.line_fields, old.image_tokens, old.footprint_pool) == ("full", 4, False)
    card = {"instructions": "short", "map": "image", "line_fields": "cell", "image_tokens": 8,
            "footprint_pool": True}  # fmt: skip
    new = PromptSettings.of(card)
    assert (new.line_fields, new.image_tokens, new.footprint_pool) == ("cell", 8, True)


def _by_drawing(cells, x, y, fx, fy, side, token_px) -> np.ndarray:
    """The tokens whose pixels change when the footprint's cells are raised to the rim."""
    container = Container((cells[0] * 25, cells[1] * 25, 200))
    hm = np.zeros(cells, dtype=np.int64)
    raised = hm.copy()
    raised[x : x + fx, y : y + fy] = 200
    changed = heightmap_image(raised, container, side) != heightmap_image(hm, container, side)
    per_side = side // token_px
    tokens = changed.reshape(per_side, token_px, per_side, token_px).any(axis=(1, 3))
    return np.flatnonzero(tokens.ravel())


@pytest.mark.parametrize("cells", [(10, 5), (25, 20), (57, 44), (300, 200)])
@pytest.mark.parametrize("side", [128, 256])
def test_footprint_tokens_are_the_tokens_drawing_the_footprint(cells, side):
    rng = np.random.default_rng(cells[0] + side)
    for _ in range(40):
        fx, fy = int(rng.integers(1, cells[0] // 2 + 1)), int(rng.integers(1, cells[1] // 2 + 1))
        x, y = int(rng.integers(0, cells[0] - fx + 1)), int(rng.integers(0, cells[1] - fy + 1))
        got = footprint_tokens(cells, x, y, fx, fy, side, 32)
        np.testing.assert_array_equal(np.sort(got), _by_drawing(cells, x, y, fx, fy, side, 32))
    # by hand: 10 x 5 cells at 12 px in a 128 px image of 4 x 4 tokens of 32 px
    assert footprint_tokens((10, 5), 2, 1, 3, 1, 128, 32).tolist() == [0, 1]  # px 24-59, 12-23
    assert footprint_tokens((10, 5), 8, 2, 2, 1, 128, 32).tolist() == [3, 7]  # px 96-119, 24-35


def test_footprint_pooling_gathers_exactly_the_footprints_tokens(pointer, states):
    tok = pointer.vlm.tokenizer
    grid = settings_grid(ImageGrid.of(pointer.vlm), PromptSettings("short", image_tokens=8))
    extras = Extras(footprint=True)
    encs = [encode(tok, s, "short", map="image", grid=grid, extras=extras) for s in states[:3]]
    batch = collate(encs, tok.pad_token_id)
    hidden = torch.randn(*batch["ids"].shape, 5, dtype=torch.float64)
    pooled = footprint_pool(hidden, batch)
    for n, (e, s) in enumerate(zip(encs, states[:3], strict=True)):
        at = np.flatnonzero(e.ids == e.image_token)
        assert (batch["visual_at"][n].numpy() == at).all()
        obs = observation_of(s)
        for k, c in enumerate(listed_of(s)):
            cells = footprint_tokens(obs.heightmap.shape, c.x, c.y, c.fx, c.fy, grid.side, 32)
            assert set(np.flatnonzero(e.footprint[k])) == set(cells.tolist())
            want = hidden[n, at[cells]].mean(0)
            torch.testing.assert_close(pooled[n, k], want, rtol=1e-12, atol=1e-12)
    assert (footprints(observation_of(states[0]), listed_of(states[0]), grid).sum(1) >= 1).all()


def test_footprint_pooling_reads_the_image_and_needs_one(pointer, states):
    state = states[-1]
    obs, listed = observation_of(state), listed_of(state)
    settings = PromptSettings("short", map="image", line_fields="cell", footprint_pool=True)
    other = replace(obs, heightmap=np.roll(obs.heightmap, 3, axis=0) + 50)
    a, b = score_listed(pointer, obs, listed, settings), score_listed(pointer, other, listed,
                                                                       settings)  # fmt: skip
    assert np.isfinite(a).all() and not np.allclose(a, b)
    blank = replace(settings, blank_map=True)
    np.testing.assert_array_equal(score_listed(pointer, obs, listed, blank),
                                  score_listed(pointer, other, listed, blank))  # fmt: skip
    with pytest.raises(ValueError, match="image"):
        PointerModel(pointer.vlm, map="text", footprint=True)
    with pytest.raises(ConfigError, match="footprint"):
        PointerTrainConfig(states=(), out="x", map="text", footprint_pool=True)
    with pytest.raises(ConfigError, match="image_tokens"):
        DaggerConfig(out="x", image_tokens=0)
    with pytest.raises(ConfigError, match="line_fields"):
        DaggerConfig(out="x", line_fields="geometry")  # type: ignore[arg-type]


def test_a_tiny_model_trains_with_all_three_and_its_card_round_trips(states, cases, tmp_path):
    path = _states_file(states, tmp_path)
    cfg = PointerTrainConfig(states=(str(path),), out=str(tmp_path / "run"),
                             model="tiny:qwen3_vl:tiny", line_vectors=False, line_fields="cell",
                             image_tokens=8, footprint_pool=True, k=8, steps=3, batch=4, warmup=1,
                             eval_every=3, heldout_every=3, threads=1)  # fmt: skip
    final = train_pointer(cfg, cases)
    card = json.loads((final / "packlab_model.json").read_text())
    assert (card["line_fields"], card["image_tokens"], card["footprint_pool"]) == ("cell", 8, True)
    assert card["line_vectors"] is False and card["map"] == "image"
    assert not (final / "onnx.json").exists()  # footprint pooling plays under torch only
    model = load_pointer(final)
    assert model.footprint and not model.lines and ImageGrid.of(model.vlm).tokens == 64
    log = (tmp_path / "run" / "log.csv").read_text()
    assert "heldout_match" in log and "loop_avg" in log
    policy = make_policy("vlm", model=str(final), runtime="torch")
    policy.reset(cases[0], 0)
    assert policy._settings == PromptSettings("short", False, "index", "image", False, "cell",
                                              8, True)  # fmt: skip
    obs, listed = observation_of(states[0]), listed_of(states[0])
    scores = score_listed(model, obs, listed, policy._settings)
    assert policy.act(obs) == listed[int(np.argmax(scores))].action
    with pytest.raises(ConfigError, match="footprint pooling"):
        export_onnx(final, check_states=1)
    with pytest.raises(ConfigError, match="image_tokens"):  # a continued run keeps the grid
        train_pointer(replace(cfg, model=str(final), out=str(tmp_path / "more"), image_tokens=4))


def test_the_cli_sets_the_three_options():
    from packlab.cli.main import build_parser
    from packlab.cli.options import config_kwargs

    args = build_parser().parse_args(
        ["train", "candidate", "--cases", "c", "--out", "o", "--line-fields", "cell",
         "--image-tokens", "8", "--footprint-pool"]
    )  # fmt: skip
    cfg = DaggerConfig(**config_kwargs(args, "train candidate", DaggerConfig))
    assert (cfg.line_fields, cfg.image_tokens, cfg.footprint_pool) == ("cell", 8, True)
    plain = build_parser().parse_args(["train", "candidate", "--cases", "c", "--out", "o"])
    cfg = DaggerConfig(**config_kwargs(plain, "train candidate", DaggerConfig))
    assert (cfg.line_fields, cfg.image_tokens, cfg.footprint_pool) == ("full", 4, False)
    assert asdict(cfg)["line_vectors"] is True


def test_cell_lines_on_another_grid_export_to_onnx_and_play_alike(states, cases, tmp_path):
    path = _states_file(states, tmp_path)
    cfg = PointerTrainConfig(states=(str(path),), out=str(tmp_path / "run"),
                             model="tiny:qwen3_vl:tiny", line_vectors=False, line_fields="cell",
                             image_tokens=2, k=8, steps=2, batch=4, warmup=1, eval_every=2,
                             heldout_every=3, threads=1)  # fmt: skip
    final = train_pointer(cfg)  # exported and checked against torch on 16 states
    card = json.loads((final / "onnx.json").read_text())
    assert card["extra"]["grid"]["per_side"] == 2
    obs, listed = observation_of(states[0]), listed_of(states[0])
    onnx = make_policy("vlm", model=str(final))
    onnx.reset(cases[0], 0)
    assert (onnx.runtime, onnx._settings.image_tokens, onnx._settings.line_fields) == (
        "onnx", 2, "cell")  # fmt: skip
    scores = score_listed(load_pointer(final), obs, listed, onnx._settings)
    assert onnx.act(obs) == listed[int(np.argmax(scores))].action


# Footprint context (``footprint_context``): the max over the footprint's tokens and the mean
# over the one-token ring around it, beside the footprint's mean.


def test_ring_tokens_on_a_small_grid():
    # 8 x 8 cells on a 128 px image: 16 px per cell, 4 x 4 tokens of 32 px (2 x 2 cells each).
    assert footprint_tokens((8, 8), 2, 2, 2, 2, 128, 32).tolist() == [5]
    assert ring_tokens((8, 8), 2, 2, 2, 2, 128, 32).tolist() == [0, 1, 2, 4, 6, 8, 9, 10]
    assert ring_tokens((8, 8), 0, 0, 1, 1, 128, 32).tolist() == [1, 4, 5]  # clipped at a corner
    assert ring_tokens((8, 8), 3, 0, 2, 1, 128, 32).tolist() == [0, 3, 4, 5, 6, 7]
    assert ring_tokens((8, 8), 0, 0, 8, 8, 128, 32).tolist() == []  # the whole image
    # A 10 x 5 container (12 px per cell): a footprint on the top token row, clipped there.
    assert footprint_tokens((10, 5), 2, 1, 3, 1, 128, 32).tolist() == [0, 1]
    assert ring_tokens((10, 5), 2, 1, 3, 1, 128, 32).tolist() == [2, 4, 5, 6]


@pytest.mark.parametrize(("cells", "side"), [((25, 25), 256), ((10, 5), 128), ((57, 40), 128)])
def test_the_ring_is_every_token_one_step_from_the_footprint(cells, side):
    rng = np.random.default_rng(3)
    per = side // 32
    for _ in range(40):
        fx, fy = int(rng.integers(1, cells[0] + 1)), int(rng.integers(1, cells[1] + 1))
        x, y = int(rng.integers(0, cells[0] - fx + 1)), int(rng.integers(0, cells[1] - fy + 1))
        under = set(footprint_tokens(cells, x, y, fx, fy, side, 32).tolist())
        want = {
            r * per + c
            for r in range(per)
            for c in range(per)
            if r * per + c not in under
            and any(max(abs(r - t // per), abs(c - t % per)) == 1 for t in under)
        }
        assert set(ring_tokens(cells, x, y, fx, fy, side, 32).tolist()) == want


def test_footprint_context_pools_mean_max_and_ring_on_a_hand_built_tensor():
    hidden = torch.tensor([[[9.0, 9.0], [1.0, -4.0], [3.0, 2.0], [5.0, 0.0], [-2.0, 6.0],
                            [9.0, 9.0]]])  # (1, 6, 2); visual tokens at 1..4  # fmt: skip
    batch = {
        "visual_at": torch.tensor([[1, 2, 3, 4]]),
        # line 0 covers tokens 0, 1 with ring 2, 3; line 1 covers token 3, empty ring; line 2
        # is padding (covers nothing).
        "footprint": torch.tensor([[[1.0, 1, 0, 0], [0, 0, 0, 1], [0, 0, 0, 0]]]),
        "ring": torch.tensor([[[0.0, 0, 1, 1], [0, 0, 0, 0], [0, 0, 0, 0]]]),
    }
    got = footprint_context_pool(hidden, batch)
    want = torch.tensor([[[2.0, -1.0, 3.0, 2.0, 1.5, 3.0],
                          [-2.0, 6.0, -2.0, 6.0, 0.0, 0.0],
                          [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]]])  # fmt: skip
    assert torch.equal(got, want)
    assert torch.equal(got[..., :2], footprint_pool(hidden, batch))  # the mean as before
    with pytest.raises(ValueError, match="rings"):
        footprint_context_pool(hidden, {k: v for k, v in batch.items() if k != "ring"})


def test_rings_are_encoded_only_with_the_context(pointer, states):
    tok = pointer.vlm.tokenizer
    grid = settings_grid(ImageGrid.of(pointer.vlm), PromptSettings("short", image_tokens=8))
    plain = encode(tok, states[0], "short", map="image", grid=grid, extras=Extras(footprint=True))
    assert plain.ring.size == 0 and "ring" not in collate([plain], tok.pad_token_id)
    extras = Extras(footprint=True, context=True)
    enc = encode(tok, states[0], "short", map="image", grid=grid, extras=extras)
    obs, listed = observation_of(states[0]), listed_of(states[0])
    assert np.array_equal(enc.ring, rings(obs, listed, grid))
    assert not (enc.ring & enc.footprint).any()
    for k, c in enumerate(listed):
        cells = ring_tokens(obs.heightmap.shape, c.x, c.y, c.fx, c.fy, grid.side, 32)
        assert np.flatnonzero(enc.ring[k]).tolist() == cells.tolist()
    settings = PromptSettings("short", map="image", footprint_pool=True, footprint_context=True)
    assert Extras.of(settings) == extras
    assert not Extras.of(replace(settings, footprint_pool=False)).context


def test_a_tiny_model_trains_with_the_context_and_its_card_round_trips(states, cases, tmp_path):
    path = _states_file(states, tmp_path)
    cfg = PointerTrainConfig(states=(str(path),), out=str(tmp_path / "run"),
                             model="tiny:qwen3_vl:tiny", line_vectors=False, line_fields="cell",
                             image_tokens=8, footprint_pool=True, footprint_context=True, k=8,
                             steps=2, batch=4, warmup=1, eval_every=2, heldout_every=3,
                             threads=1)  # fmt: skip
    final = train_pointer(cfg, cases[:1])
    card = json.loads((final / "packlab_model.json").read_text())
    assert (card["footprint_pool"], card["footprint_context"]) == (True, True)
    assert not (final / "onnx.json").exists()
    model = load_pointer(final)
    hidden = model.text.config.hidden_size
    assert model.footprint and model.context
    assert model.head.mlp[0].in_features == 4 * hidden
    policy = make_policy("vlm", model=str(final), runtime="torch")
    policy.reset(cases[0], 0)
    assert policy._settings.footprint_context
    obs, listed = observation_of(states[0]), listed_of(states[0])
    scores = score_listed(model, obs, listed, policy._settings)
    assert policy.act(obs) == listed[int(np.argmax(scores))].action
    again = score_listed(load_pointer(final), obs, listed, policy._settings)
    assert np.allclose(scores, again)
    with pytest.raises(ConfigError, match="footprint_context"):
        export_onnx(final, check_states=1)
    with pytest.raises(ConfigError, match="footprint_context"):  # a continued run keeps it
        train_pointer(replace(cfg, model=str(final), out=str(tmp_path / "more"),
                              footprint_context=False))  # fmt: skip


def test_a_footprint_model_saved_without_the_context_key_loads_as_before(pointer, tmp_path):
    meta = {"instructions": "short", "map": "image", "line_vectors": False,
            "footprint_pool": True}  # fmt: skip
    final = save_pointer(pointer, tmp_path / "old", meta)
    card = json.loads((final / "packlab_model.json").read_text())
    assert "footprint_context" not in card
    model = load_pointer(final)
    assert model.footprint and not model.context
    assert model.head.mlp[0].in_features == 2 * model.text.config.hidden_size
    assert not PromptSettings.of(card).footprint_context
    for a, b in zip(pointer.head.parameters(), model.head.parameters(), strict=True):
        assert torch.equal(a, b)


def test_the_context_needs_footprint_pooling_and_the_cli_sets_it(pointer):
    from packlab.cli.main import build_parser
    from packlab.cli.options import config_kwargs

    args = build_parser().parse_args(
        ["train", "candidate", "--cases", "c", "--out", "o", "--footprint-pool",
         "--footprint-context"]
    )  # fmt: skip
    cfg = DaggerConfig(**config_kwargs(args, "train candidate", DaggerConfig))
    assert (cfg.footprint_pool, cfg.footprint_context) == (True, True)
    alone = build_parser().parse_args(
        ["train", "candidate", "--cases", "c", "--out", "o", "--footprint-context"]
    )
    with pytest.raises(ConfigError, match="footprint_pool"):
        DaggerConfig(**config_kwargs(alone, "train candidate", DaggerConfig))
    with pytest.raises(ConfigError, match="footprint_pool"):
        PointerTrainConfig(states=(), out="x", footprint_context=True)
    with pytest.raises(ValueError, match="footprint pooling"):
        PointerModel(pointer.vlm, map="image", context=True)
