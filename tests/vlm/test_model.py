"""Tiny Qwen-VL-family models: build, forward with images, label masking, save/load round trip.

Needs the vlm extra (torch, transformers); skipped in the core install.
"""

from __future__ import annotations

import json

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")

from PIL import Image

from packlab.core.choices import ModelDType, choices
from packlab.core.errors import ConfigError
from packlab.core.types import Action
from packlab.vlm.data.encoding import (
    ProcessingConfig,
    collate,
    encode,
    encode_fitting,
)
from packlab.vlm.model.chatml import IMAGE_PAD
from packlab.vlm.model.checkpoint import (
    FAMILIES,
    TORCH_DTYPES,
    family_of,
    load_model,
    save_model,
    torch_dtype,
)
from packlab.vlm.model.spec import make_model
from packlab.vlm.model.tiny import build_tiny_model, mrope_sections
from packlab.vlm.model.tokenizer import TOKENIZER_NAME, build_tokenizer
from packlab.vlm.prompt.render import (
    PROMPT_VERSION,
    PromptOptions,
    TurnState,
    drop_oldest_step,
    render_messages,
)

pytestmark = pytest.mark.torch

# 224 px images: Qwen3-VL / Qwen3.5 merge 2x2 patches of 16 px -> 7 x 7 = 49 visual tokens;
# Qwen2.5-VL merges 2x2 patches of 14 px -> 8 x 8 = 64.
VISUAL_TOKENS = {"qwen3_5": 49, "qwen3_vl": 49, "qwen2_5_vl": 64}
ANSWER = Action(object_id=1, rotation=1, x=3, y=12)


@pytest.fixture(scope="module", params=FAMILIES)
def vlm(request):
    return build_tiny_model(request.param, "tiny", seed=0)


def _with_images(fixed_state):
    """The golden state with real 224 px images in place of the dataset paths."""
    container, past, current = fixed_state
    colours = iter([(200, 0, 0), (0, 200, 0), (0, 0, 200)])

    def img(t: TurnState) -> TurnState:
        return TurnState(
            Image.new("RGB", (224, 224), next(colours)), t.shown, t.step_index, t.remaining
        )

    return container, [(img(t), a) for t, a in past], img(current)


def _greedy(vlm, messages, n=8):
    enc = encode(messages, vlm.tokenizer, vlm.image_processor)
    batch = collate([enc], vlm.tokenizer.pad_token_id, padding_side="left")
    with torch.no_grad():
        out = vlm.model.generate(**batch, max_new_tokens=n, do_sample=False)
    return out[0, enc.length :].tolist()


def test_forward_with_images(vlm, fixed_state):
    container, past, current = _with_images(fixed_state)
    messages = render_messages(container, past[:1], current)
    enc = encode(messages, vlm.tokenizer, vlm.image_processor)
    assert enc.image_grid_thw.shape == (2, 3)
    assert int(enc.mm_token_type_ids.sum()) == 2 * VISUAL_TOKENS[vlm.family]
    batch = collate([enc, enc], vlm.tokenizer.pad_token_id)
    with torch.no_grad():
        out = vlm.model(**batch, labels=batch["input_ids"])
    assert out.logits.shape[:2] == (2, enc.length)
    assert torch.isfinite(out.loss)
    # Random weights over a ~640-token vocabulary: loss near ln(vocab).
    assert 4.0 < out.loss.item() < 9.0


def test_save_load_gives_identical_generations(vlm, fixed_state, tmp_path):
    container, _, current = _with_images(fixed_state)
    messages = render_messages(container, [], current)
    before = _greedy(vlm, messages)
    save_model(vlm, tmp_path / "ckpt", extra_meta={"note": "round trip"})
    assert family_of(tmp_path / "ckpt") == vlm.family
    loaded = load_model(tmp_path / "ckpt")
    assert type(loaded.model) is type(vlm.model)
    assert loaded.meta["prompt_version"] == PROMPT_VERSION and loaded.meta["note"] == "round trip"
    assert _greedy(loaded, messages) == before
    # Same tokenizer after the round trip.
    text = messages[-1]["content"][-1]["text"]
    assert loaded.tokenizer.encode(text, add_special_tokens=False) == vlm.tokenizer.encode(
        text, add_special_tokens=False
    )


def test_blank_and_no_image_ablations_encode(vlm, fixed_state):
    container, past, current = fixed_state  # dataset-style: blank marker, no files needed
    blank = render_messages(container, past, current, PromptOptions(image="blank"))
    enc = encode(blank, vlm.tokenizer, vlm.image_processor, config=ProcessingConfig(image_size=224))
    assert int(enc.mm_token_type_ids.sum()) == 3 * VISUAL_TOKENS[vlm.family]
    assert bool(
        (enc.pixel_values == enc.pixel_values[0]).all()
    )  # every patch the same: no information
    none = render_messages(container, past, current, PromptOptions(image="none"))
    enc = encode(none, vlm.tokenizer, vlm.image_processor)
    assert enc.pixel_values is None and int(enc.mm_token_type_ids.sum()) == 0
    with torch.no_grad():
        out = vlm.model(**collate([enc], vlm.tokenizer.pad_token_id))
    assert torch.isfinite(out.logits).all()


def test_dataset_image_paths_resolve_against_root(fixed_state, tmp_path):
    vlm = build_tiny_model("qwen3_vl")
    container, _, current = fixed_state
    (tmp_path / "images/ep0").mkdir(parents=True)
    Image.new("RGB", (224, 224), (9, 9, 9)).save(tmp_path / current.image)
    enc = encode(
        render_messages(container, [], current),
        vlm.tokenizer,
        vlm.image_processor,
        config=ProcessingConfig(image_root=str(tmp_path)),
    )
    assert enc.image_grid_thw.tolist() == [[1, 14, 14]]


def test_encode_fitting_drops_oldest_steps(fixed_state):
    vlm = build_tiny_model("qwen3_5")
    container, past, current = fixed_state
    messages = render_messages(container, past, current, PromptOptions(image="none"))
    full = encode(messages, vlm.tokenizer, vlm.image_processor).length
    only = encode(
        render_messages(container, [], current, PromptOptions(image="none")),
        vlm.tokenizer,
        vlm.image_processor,
    ).length
    enc, dropped = encode_fitting(
        messages, vlm.tokenizer, vlm.image_processor, config=ProcessingConfig(max_length=full - 1)
    )
    assert dropped == 1 and enc.length < full
    enc, dropped = encode_fitting(
        messages, vlm.tokenizer, vlm.image_processor, config=ProcessingConfig(max_length=only)
    )
    assert dropped == 2 and enc.length == only
    with pytest.raises(ValueError, match="without any history"):
        encode_fitting(
            messages,
            vlm.tokenizer,
            vlm.image_processor,
            config=ProcessingConfig(max_length=only - 1),
        )


def test_drop_oldest_step_per_history_mode(fixed_state):
    container, past, current = fixed_state
    full = render_messages(container, past, current)
    assert [m["role"] for m in drop_oldest_step(full)] == ["system", "user", "assistant", "user"]
    no_act = render_messages(container, past, current, PromptOptions(history="no_actions"))
    assert [m["role"] for m in drop_oldest_step(no_act)] == ["system", "user", "user"]
    assert drop_oldest_step(render_messages(container, [], current)) is None


def test_collate_padding_sides():
    from packlab.vlm.data.encoding import Encoded

    def ex(n):
        ids = torch.arange(1, n + 1)
        return Encoded(ids, torch.zeros(n, dtype=torch.long), None, None)

    right = collate([ex(2), ex(4)], pad_id=0, padding_side="right")
    assert right["input_ids"].tolist() == [[1, 2, 0, 0], [1, 2, 3, 4]]
    assert right["attention_mask"].tolist() == [[1, 1, 0, 0], [1, 1, 1, 1]]
    left = collate([ex(2), ex(4)], pad_id=0)  # prompts for generation: left by default
    assert left["input_ids"].tolist()[0] == [0, 0, 1, 2]
    assert left["attention_mask"].tolist()[0] == [0, 0, 1, 1]
    assert "pixel_values" not in left and "labels" not in left


@pytest.mark.parametrize(
    "half,ref",
    [(4, (11, 11, 10)), (16, (24, 20, 20)), (16, (16, 24, 24)), (64, (24, 20, 20)), (3, (1, 1, 1))],
)
def test_mrope_sections_add_up(half, ref):
    s = mrope_sections(half, ref)
    assert sum(s) == half and min(s) >= 1


def test_mrope_sections_too_few():
    with pytest.raises(ValueError):
        mrope_sections(2, (11, 11, 10))


def test_unknown_family_and_size():
    with pytest.raises(ValueError, match="family"):
        build_tiny_model("llava")
    with pytest.raises(ValueError, match="size"):
        build_tiny_model("qwen3_5", "huge")


def _param_dtypes(vlm) -> set:
    return {p.dtype for p in vlm.model.parameters()}


def _write_config(folder, vocab_size: int = 151936):
    """A config.json as a real Qwen3-VL checkpoint has one: the full vocabulary and the real
    vocabulary's special token ids (the class defaults), but tiny dimensions."""
    folder.mkdir(parents=True, exist_ok=True)
    config = {
        "model_type": "qwen3_vl",
        "text_config": {
            "vocab_size": vocab_size,
            "hidden_size": 64,
            "intermediate_size": 128,
            "num_hidden_layers": 2,
            "num_attention_heads": 2,
            "num_key_value_heads": 1,
            "head_dim": 32,
            "rope_parameters": {
                "rope_type": "default",
                "rope_theta": 5_000_000.0,
                "mrope_interleaved": True,
                "mrope_section": mrope_sections(16, (24, 20, 20)),
            },
        },
        "vision_config": {
            "depth": 1,
            "hidden_size": 32,
            "num_heads": 2,
            "intermediate_size": 64,
            "out_hidden_size": 64,
            "num_position_embeddings": 256,
            "deepstack_visual_indexes": [0],
        },
    }
    (folder / "config.json").write_text(json.dumps(config))
    return folder / "config.json"


def test_torch_dtypes_cover_the_choices():
    assert tuple(TORCH_DTYPES) == choices(ModelDType)
    assert torch_dtype("bf16") is torch.bfloat16


@pytest.mark.parametrize("family", FAMILIES)
def test_tiny_spec_builds_in_bf16(family):
    vlm = make_model(f"tiny:{family}:tiny", dtype="bf16")
    assert _param_dtypes(vlm) == {torch.bfloat16}
    # fp32 stays the default, and the dtype does not change what the seed draws.
    fp32 = make_model(f"tiny:{family}:tiny")
    assert _param_dtypes(fp32) == {torch.float32}
    first = next(iter(fp32.model.state_dict()))
    assert torch.equal(
        vlm.model.state_dict()[first], fp32.model.state_dict()[first].to(torch.bfloat16)
    )


def test_config_spec_with_only_config_json(tmp_path, fixed_state):
    _write_config(tmp_path / "ckpt")
    vlm = make_model(f"config:{tmp_path / 'ckpt'}", seed=1, dtype="bf16")
    assert _param_dtypes(vlm) == {torch.bfloat16}
    assert vlm.family == "qwen3_vl" and vlm.meta["tokenizer"] == TOKENIZER_NAME
    # The project tokenizer, its ids in the config in place of the real vocabulary's.
    assert len(vlm.tokenizer) == len(build_tokenizer(seed=1))
    assert len(vlm.tokenizer) <= vlm.model.config.text_config.vocab_size == 151936
    assert vlm.model.config.image_token_id == vlm.tokenizer.convert_tokens_to_ids(IMAGE_PAD)
    container, _, current = _with_images(fixed_state)
    enc = encode(render_messages(container, [], current), vlm.tokenizer, vlm.image_processor)
    with torch.no_grad():
        out = vlm.model(**collate([enc], vlm.tokenizer.pad_token_id))
    assert out.logits.dtype == torch.bfloat16 and bool(torch.isfinite(out.logits).all())
    # The file itself names the same model; the seed fixes the weights.
    again = make_model(f"config:{tmp_path / 'ckpt' / 'config.json'}", seed=1, dtype="bf16")
    name, weight = next(iter(vlm.model.state_dict().items()))
    assert torch.equal(again.model.state_dict()[name], weight)


def test_config_spec_uses_the_directory_tokenizer(tmp_path):
    saved = build_tiny_model("qwen3_5", "tiny", seed=4)
    save_model(saved, tmp_path / "ckpt")
    vlm = make_model(f"config:{tmp_path / 'ckpt'}", seed=0)
    assert vlm.tokenizer.get_vocab() == saved.tokenizer.get_vocab()
    assert vlm.meta["tokenizer"] == TOKENIZER_NAME and vlm.family == "qwen3_5"


def test_checkpoint_loads_in_the_asked_dtype(tmp_path):
    save_model(build_tiny_model("qwen3_vl", "tiny"), tmp_path / "ckpt")
    assert _param_dtypes(make_model(str(tmp_path / "ckpt"), dtype="bf16")) == {torch.bfloat16}
    assert _param_dtypes(make_model(str(tmp_path / "ckpt"))) == {torch.float32}


def test_config_vocab_smaller_than_the_tokenizer(tmp_path):
    file = _write_config(tmp_path / "ckpt", vocab_size=100)
    with pytest.raises(ConfigError, match=r"text_config\.vocab_size = 100") as err:
        make_model(f"config:{tmp_path / 'ckpt'}")
    assert str(file) in str(err.value)


@pytest.mark.parametrize(
    "spec,dtype,named",
    [
        ("tiny:qwen3_vl:tiny", "bf32", "'bf32'"),
        ("tiny:qwen3_vl:tiny", "float16", "'float16'"),
        ("tiny:llava:tiny", "fp32", "llava"),
        ("tiny:qwen3_vl", "fp32", "'tiny:qwen3_vl'"),
        ("no/such/dir", "fp32", "'no/such/dir'"),
        ("config:no/such/dir", "fp32", "no/such/dir"),
    ],
)
def test_bad_spec_or_dtype(spec, dtype, named):
    with pytest.raises(ConfigError, match=named):
        make_model(spec, dtype=dtype)
