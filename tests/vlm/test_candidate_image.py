"""Candidate mode with the heightmap as an image (tiny Qwen3-VL, CPU): the patches are the
transformers processor's, normalised with each family's own mean and std, the prompt holds one
pad per visual token, the image reaches the scores (and a blank one does not), batches pad
without changing scores, soft targets reduce to the label's cross-entropy, ``map`` and the
normalisation survive save/load (old directories read as text and 0.5), and the device and
dtype settings are checked."""

from __future__ import annotations

import json
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
from packlab.vlm.candidate.compose import state_messages
from packlab.vlm.candidate.device import autocast, placement, resolve_device
from packlab.vlm.candidate.image import QWEN3_MEAN, QWEN3_STD, heightmap_image, patchify
from packlab.vlm.candidate.pointer import (
    ImageGrid,
    PointerModel,
    collate,
    encode,
    encode_observation,
    soft_loss,
)
from packlab.vlm.candidate.recipe import DaggerConfig
from packlab.vlm.candidate.saved import load_pointer, save_pointer
from packlab.vlm.candidate.scoring import PromptSettings, score_listed
from packlab.vlm.candidate.states import listed_of, observation_of
from packlab.vlm.candidate.train import PointerTrainConfig
from packlab.vlm.model.checkpoint import image_processor_for
from packlab.vlm.model.tiny import build_tiny_model
from packlab.vlm.model.tokenizer import IMAGE_PAD, VISION_END, VISION_START
from packlab.vlm.prompt.render import PROMPT_VERSION

# One torch thread, and the sdf-labelled states of one medium case (tests/vlm/conftest.py).
pytestmark = [pytest.mark.torch, pytest.mark.usefixtures("one_torch_thread")]

PROPOSER = ProposerConfig(k=8, rule="lowest")
CARD = {"proposer": asdict(PROPOSER), "instructions": "short", "prompt_version": PROMPT_VERSION}
#: OpenAI CLIP's normalisation, Qwen2.5-VL's processor's.
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)


@pytest.fixture(scope="module")
def pointer():
    torch.manual_seed(0)
    return PointerModel(build_tiny_model("qwen3_vl", "tiny")).eval()


def _scores(model, observation, listed, map_: str) -> np.ndarray:
    return score_listed(model, observation, listed, PromptSettings("short", map=map_))


def test_patches_are_the_qwen_processors():
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, size=(2, 128, 128), dtype=np.uint8)
    pixels, grid = patchify(images, 16, 2, 2)
    rgb = [np.repeat(im[..., None], 3, axis=-1) for im in images]
    ref = image_processor_for("qwen3_vl")(images=rgb, return_tensors="np")
    np.testing.assert_array_equal(grid, ref["image_grid_thw"])
    np.testing.assert_allclose(pixels, ref["pixel_values"], rtol=0, atol=1e-5)


def test_the_image_is_the_heightmap_in_rim_fractions_with_walls_around():
    container = Container((250, 125, 200))  # 10 x 5 cells
    hm = np.zeros((10, 5), dtype=np.int32)
    hm[2, 1] = 100  # half the rim at x = 2, y = 1
    im = heightmap_image(hm, container, 128)
    assert im.shape == (128, 128) and im.dtype == np.uint8
    scale = 128 // 10
    assert im[1 * scale, 2 * scale] == 127 and im[0, 0] == 0
    assert (im[5 * scale :, :] == 255).all() and (im[:, 10 * scale :] == 255).all()  # walls
    big = heightmap_image(np.full((300, 200), 200), Container((7500, 5000, 200)), 128)
    assert big.shape == (128, 128) and big.max() == 255  # max-pooled, not cut off


def test_the_prompt_holds_one_pad_per_visual_token(pointer, states):
    tok, grid = pointer.vlm.tokenizer, ImageGrid.of(pointer.vlm)
    assert (grid.side, grid.tokens) == (128, 16)
    for map_ in ("image", "both", "blank"):
        enc = encode(tok, states[0], "short", map=map_, grid=grid)
        pads = int((enc.ids == tok.convert_tokens_to_ids(IMAGE_PAD)).sum())
        batch = collate([enc], tok.pad_token_id)
        thw = batch["image_grid_thw"][0]
        assert pads == grid.tokens == int(thw.prod()) // grid.merge**2
        assert int(batch["mm_token_type_ids"].sum()) == pads
        assert batch["pixel_values"].shape == (int(thw.prod()), 3 * 2 * 16 * 16)
        text = tok.decode(enc.ids)
        assert text.count(VISION_START) == text.count(VISION_END) == 1
        assert ("Map " in text) == (map_ == "both")
    text = encode(tok, states[0], "short", map="text", grid=grid)
    assert text.image is None and "pixel_values" not in collate([text], tok.pad_token_id)


def test_the_image_changes_the_scores_and_a_blank_one_does_not(pointer, states):
    state = states[-1]
    obs, listed = observation_of(state), listed_of(state)
    other = replace(obs, heightmap=np.roll(obs.heightmap, 3, axis=0) + 50)
    for map_, changes in (("image", True), ("both", True), ("text", True), ("blank", False)):
        a, b = _scores(pointer, obs, listed, map_), _scores(pointer, other, listed, map_)
        assert a.shape == (len(listed),) and np.isfinite(a).all()
        assert (np.abs(a - b).max() > 1e-6) == changes, map_


def test_padding_in_an_image_batch_changes_no_score(pointer, states):
    tok = pointer.vlm.tokenizer
    encoded = [encode(tok, s, "short", map="image") for s in states[:5]]
    assert len({len(e.ids) for e in encoded}) > 1  # the batch really pads
    with torch.inference_mode():
        together = pointer.score(collate(encoded, tok.pad_token_id))
        for n, e in enumerate(encoded):
            alone = pointer.score(collate([e], tok.pad_token_id))[0]
            torch.testing.assert_close(together[n, : len(e.ends)], alone, rtol=0, atol=1e-5)


def test_soft_targets_reduce_to_the_label_when_one_hot(pointer, states):
    tok = pointer.vlm.tokenizer
    plain = [encode(tok, s, "short") for s in states[:4]]
    onehot = [replace(e, soft=np.eye(len(e.ends), dtype=np.float32)[e.label]) for e in plain]
    with torch.inference_mode():
        b, o = collate(plain, tok.pad_token_id), collate(onehot, tok.pad_token_id)
        torch.testing.assert_close(b["targets"], o["targets"])
        scores = pointer.score(b)
        hard = torch.nn.functional.cross_entropy(scores, b["labels"])
        torch.testing.assert_close(soft_loss(scores, o["targets"], o["valid"]), hard)
        spread = [replace(e, soft=np.full(len(e.ends), 1 / len(e.ends), np.float32)) for e in plain]
        s = collate(spread, tok.pad_token_id)
        assert soft_loss(scores, s["targets"], s["valid"]) != pytest.approx(float(hard))
    uniform = np.full(len(states[0].listed), 1 / len(states[0].listed))
    if hasattr(states[0], "soft"):  # the states' own soft field reaches the targets
        soft_state = msgspec.structs.replace(states[0], soft=tuple(uniform))
        np.testing.assert_allclose(encode(tok, soft_state, "short").soft, uniform, rtol=1e-6)


def test_an_image_model_round_trips_and_plays(pointer, states, cases, tmp_path):
    path = save_pointer(pointer, tmp_path / "ptr", {**CARD, "map": "image"})
    back = load_pointer(path)
    assert back.vlm.meta["map"] == "image"
    state = states[0]
    obs, listed = observation_of(state), listed_of(state)
    before = _scores(pointer, obs, listed, "image")
    np.testing.assert_allclose(_scores(back, obs, listed, "image"), before, rtol=0, atol=1e-6)
    policy = make_policy("vlm", model=str(path), runtime="torch")  # saved, not exported
    policy.reset(cases[0], 0)
    assert policy._settings.map == "image"
    assert policy.act(obs) == listed[int(np.argmax(before))].action


def test_a_directory_saved_before_maps_loads_as_text(pointer, states, cases, tmp_path):
    path = save_pointer(pointer, tmp_path / "old", CARD)
    meta = json.loads((path / "packlab_model.json").read_text())
    assert "map" not in meta  # what an older packlab wrote
    assert load_pointer(path).vlm.meta["map"] == "text"
    policy = make_policy("vlm", model=str(path), runtime="torch")
    policy.reset(cases[0], 0)
    assert policy._settings.map == "text"
    obs, listed = observation_of(states[0]), listed_of(states[0])
    assert policy.act(obs) == listed[int(np.argmax(_scores(pointer, obs, listed, "text")))].action


def test_map_settings_are_checked_and_default_to_image():
    assert PointerTrainConfig(states=(), out="x").map == "image"
    assert DaggerConfig(out="x").map == "image"
    with pytest.raises(ConfigError, match="map"):
        PointerTrainConfig(states=(), out="x", map="picture")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="map"):
        DaggerConfig(out="x", map="picture")  # type: ignore[arg-type]


def test_a_live_step_encodes_as_a_stored_one(pointer, states):
    tok = pointer.vlm.tokenizer
    s = states[0]
    stored = encode(tok, s, "short", map="both")
    live = encode_observation(tok, observation_of(s), listed_of(s), "short", map="both")
    np.testing.assert_array_equal(stored.ids, live.ids)
    np.testing.assert_array_equal(stored.image, live.image)


def test_the_full_legend_describes_the_map_shown(states):
    for map_, image in (("text", False), ("both", False), ("image", True), ("blank", True)):
        system = state_messages(states[0], "full", map=map_)[0]["content"][0]["text"]
        assert ("Image: the heightmap" in system) == image
        assert ("Map: one line per" in system) == (not image)


def test_the_loss_trains_the_vision_tower(states):
    for map_, trained in (("image", True), ("text", False)):
        torch.manual_seed(0)
        model = PointerModel(build_tiny_model("qwen3_vl", "tiny"), map=map_).train()
        tok = model.vlm.tokenizer
        weight = model.vlm.model.model.visual.patch_embed.proj.weight
        assert any(p is weight for p in model.parameters()) == trained, map_  # the optimizer's
        b = collate([encode(tok, s, "short", map=map_) for s in states[:4]], tok.pad_token_id)
        soft_loss(model.score(b), b["targets"], b["valid"]).backward()
        assert (weight.grad is not None and float(weight.grad.abs().sum()) > 0) == trained, map_
        assert any(k.startswith("visual.") for k in model.state_dict()) == trained, map_


def _processor_pixels(family: str, images: np.ndarray) -> np.ndarray:
    """transformers' processor of the family on the grey images copied to RGB."""
    rgb = [np.repeat(im[..., None], 3, axis=-1) for im in images]
    return image_processor_for(family)(images=rgb, return_tensors="np")["pixel_values"]


def test_the_default_normalisation_is_the_one_every_earlier_model_used():
    # Bit for bit (v * 2 / 255 - 1), so that models trained and exported before the
    # normalisation was configurable score exactly as they did.
    images = np.random.default_rng(1).integers(0, 256, size=(2, 128, 128), dtype=np.uint8)
    pixels, _ = patchify(images, 16, 2, 2)
    values = pixels.reshape(2, 8 // 2, 8 // 2, 2, 2, 3, 2, 16, 16)  # (b, ., ., ., ., c, t, p, p)
    ref = images.astype(np.float32) * (2.0 / 255.0) - 1.0
    first = values[0, 0, 0, 0, 0, 0, 0]  # the top-left patch of image 0, channel 0, frame 0
    np.testing.assert_array_equal(first, ref[0, :16, :16])
    assert np.array_equal(pixels, patchify(images, 16, 2, 2, QWEN3_MEAN, QWEN3_STD)[0])


@pytest.mark.parametrize(
    ("family", "mean", "std"),
    [("qwen2_5_vl", CLIP_MEAN, CLIP_STD), ("qwen3_vl", QWEN3_MEAN, QWEN3_STD)],
)
def test_each_family_normalises_with_its_own_processor(states, family, mean, std):
    vlm = build_tiny_model(family, "tiny")
    grid = ImageGrid.of(vlm)
    assert (grid.mean, grid.std) == (tuple(mean), tuple(std))
    enc = encode(vlm.tokenizer, states[-1], "short", map="image", grid=grid)
    pixels = collate([enc], vlm.tokenizer.pad_token_id)["pixel_values"].numpy()
    np.testing.assert_allclose(pixels, _processor_pixels(family, enc.image[None]), atol=1e-5)
    floor = pixels.reshape(len(pixels), 3, -1)[:, :, 0]  # a pixel's value in the 3 channels
    channels = {tuple(np.round(row, 4)) for row in floor}
    assert len(channels) > 1 and all(len(set(c)) == (3 if family == "qwen2_5_vl" else 1)
                                     for c in channels)  # fmt: skip


def test_a_saved_model_keeps_its_normalisation_and_older_ones_read_as_qwen3(states, tmp_path):
    torch.manual_seed(0)
    model = PointerModel(build_tiny_model("qwen2_5_vl", "tiny"), map="image").eval()
    path = save_pointer(model, tmp_path / "clip", {**CARD, "map": "image"})
    meta = json.loads((path / "packlab_model.json").read_text())
    assert meta["image_mean"] == list(CLIP_MEAN) and meta["image_std"] == list(CLIP_STD)
    assert ImageGrid.of(load_pointer(path).vlm) == ImageGrid.of(model.vlm)
    for key in ("image_mean", "image_std"):  # what a packlab before the record wrote
        del meta[key]
    (path / "packlab_model.json").write_text(json.dumps(meta))
    old = ImageGrid.of(load_pointer(path).vlm)
    assert (old.mean, old.std) == (QWEN3_MEAN, QWEN3_STD)  # what it was trained with


def test_device_and_dtype_settings_name_the_field():
    for config in (DaggerConfig, PointerTrainConfig):
        extra = {"states": ()} if config is PointerTrainConfig else {}
        name = config.__name__
        with pytest.raises(ConfigError, match=rf"{name}\.device = 'xyz'"):
            config(out="x", device="xyz", **extra)
        with pytest.raises(ConfigError, match=rf"{name}\.dtype = 'fp16'"):
            config(out="x", dtype="fp16", **extra)
        with pytest.raises(ConfigError, match=rf"{name}\.dtype = 'bf16': device 'cpu'"):
            config(out="x", device="cpu", dtype="bf16", **extra)
        for device in ("auto", "cpu", "cuda", "cuda:1"):  # names torch takes
            assert config(out="x", device=device, **extra).device == device
    assert (DaggerConfig(out="x").device, DaggerConfig(out="x").dtype) == ("auto", "fp32")


def test_auto_resolves_to_the_cpu_without_a_gpu(monkeypatch):
    if not torch.cuda.is_available():
        assert resolve_device("DaggerConfig", "auto") == "cpu"  # this machine
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert placement("DaggerConfig", "auto", "fp32") == "cpu"
    with pytest.raises(ConfigError, match=r"DaggerConfig\.dtype = 'bf16': device 'auto' \(cpu"):
        placement("DaggerConfig", "auto", "bf16")
    with pytest.raises(ConfigError, match=r"DaggerConfig\.device = 'cuda:1': torch sees 0"):
        placement("DaggerConfig", "cuda:1", "fp32")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("DaggerConfig", "auto") == "cuda"


def test_fp32_runs_without_autocast(pointer, states):
    tok = pointer.vlm.tokenizer
    batch = collate([encode(tok, states[0], "short", map="image")], tok.pad_token_id)
    with torch.inference_mode(), autocast("cpu", "fp32"):
        assert not torch.is_autocast_enabled("cpu")
        assert pointer.score(batch).dtype == torch.float32
