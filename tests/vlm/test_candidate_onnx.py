"""The candidate-mode VLM on ONNX Runtime: the ONNX path builds the torch path's very prompt
text, token ids, M-RoPE positions and normalised pixels, its graphs pick the same listed placement
as torch on
generated states (the shipped model and tiny random ones), it plays without importing torch,
and every way a directory can be unfit says what to run."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest

from packlab.core.errors import ConfigError
from packlab.policies.onnx_model import CARD_FILE, ONNX_FORMAT
from packlab.policies.registry import make_policy
from packlab.vlm.candidate.json_tokenizer import JsonTokenizer
from packlab.vlm.infer.policy import SHIPPED_MODEL_DIR

SHIPPED = Path(SHIPPED_MODEL_DIR)
needs_export = pytest.mark.skipif(
    not (SHIPPED / CARD_FILE).is_file(), reason="no ONNX export of vlm-small in this install"
)


def _torch():
    pytest.importorskip("torch")
    pytest.importorskip("transformers")
    import torch

    torch.set_num_threads(1)
    return torch


@pytest.fixture(scope="module")
def generated():
    """Varied observations with their listed placements: generated cases (packlab.datagen)
    played with random listed picks."""
    _torch()
    from packlab.datagen.generator import generate_cases
    from packlab.policies.candidates import ProposerConfig
    from packlab.vlm.candidate.onnx_export import check_observations

    cases = generate_cases("easy", 2, 21, validate=False, domain="train") + generate_cases(
        "hard", 2, 21, validate=False, domain="train"
    )
    return check_observations(40, ProposerConfig(k=16), cases)


def _copy_shipped(tmp_path: Path) -> Path:
    out = tmp_path / "vlm-small"
    shutil.copytree(SHIPPED, out)
    return out


# -- the inputs: prompt text, token ids, positions ------------------------------------------


@pytest.mark.torch
@pytest.mark.parametrize("map", ["image", "text", "both"])
def test_prompt_text_and_token_ids_equal_the_transformers_path(generated, map):
    from packlab.vlm.candidate.compose import observation_messages
    from packlab.vlm.candidate.encoding import QWEN3_GRID, encode_observation, prompt_text
    from packlab.vlm.model.checkpoint import load_model

    hf = load_model(SHIPPED).tokenizer
    plain = JsonTokenizer(SHIPPED)
    for observation, listed in generated:
        messages = observation_messages(observation, listed, "short", map=map)
        assert prompt_text(plain, messages) == prompt_text(hf, messages)
        a, b = (encode_observation(t, observation, listed, "short", map=map, grid=QWEN3_GRID,
                                   lines=True) for t in (hf, plain))  # fmt: skip
        for field in ("ids", "ends", "starts", "vectors"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
        assert a.image_token == b.image_token


@pytest.mark.torch
def test_rope_positions_equal_transformers_get_rope_index(generated):
    _torch()
    from packlab.vlm.candidate.encoding import ImageGrid, encode_observation
    from packlab.vlm.candidate.pointer import collate
    from packlab.vlm.candidate.rope import rope_positions
    from packlab.vlm.model.tiny import build_tiny_model

    vlm = build_tiny_model("qwen3_vl", "tiny")
    grid = ImageGrid.of(vlm)
    for observation, listed in generated[:12]:
        enc = encode_observation(vlm.tokenizer, observation, listed, "short", map="image",
                                 grid=grid)  # fmt: skip
        batch = collate([enc], vlm.tokenizer.pad_token_id)
        ref, _ = vlm.model.model.get_rope_index(
            batch["ids"], batch["mm_token_type_ids"], batch["image_grid_thw"], None,
            attention_mask=batch["mask"],
        )  # fmt: skip
        got = rope_positions(enc.ids, enc.image_token, grid)
        np.testing.assert_array_equal(got, ref.numpy())
        assert got.max() < len(enc.ids)  # the image's 4 x 4 tokens take 4 positions, not 16
    text = rope_positions(np.arange(7), -1, None)
    assert text.shape == (3, 1, 7) and (text == np.arange(7)).all()
    with pytest.raises(ValueError, match="image tokens"):  # pads that are not one image
        rope_positions(np.array([1, 6, 6, 2]), 6, grid)


def test_the_python_chat_template_is_the_saved_one():
    from packlab.vlm.model.chatml import CHAT_TEMPLATE, is_project_template, render_chat

    assert is_project_template((SHIPPED / "chat_template.jinja").read_text())
    messages = [
        {"role": "system", "content": "plain"},
        {"role": "user", "content": [{"type": "image"}, {"type": "text", "text": "a\nb"}]},
    ]
    assert render_chat(messages) == (
        "<|im_start|>system\nplain<|im_end|>\n<|im_start|>user\n"
        "<|vision_start|><|image_pad|><|vision_end|>a\nb<|im_end|>\n<|im_start|>assistant\n"
    )
    assert not render_chat(messages, add_generation_prompt=False).endswith("assistant\n")
    assert "jinja" not in CHAT_TEMPLATE and "{%-" in CHAT_TEMPLATE


# -- the graphs pick what torch picks --------------------------------------------------------


def _agreement(torch_model, onnx_model, states, settings) -> tuple[int, float]:
    from packlab.vlm.candidate import onnx_scoring, scoring

    equal, worst = 0, 0.0
    for observation, listed in states:
        a = scoring.score_listed(torch_model, observation, listed, settings)
        b = onnx_scoring.score_listed(onnx_model, observation, listed, settings)
        assert a.shape == b.shape == (len(listed),)
        equal += int(np.argmax(a) == np.argmax(b))
        worst = max(worst, float(np.abs(a - b).max()))
    return equal, worst


@pytest.mark.torch
@needs_export
@pytest.mark.parametrize("blank", [False, True])
def test_the_shipped_model_picks_as_torch_on_generated_states(generated, blank):
    _torch()
    from packlab.vlm.candidate.encoding import PromptSettings
    from packlab.vlm.candidate.onnx_scoring import load_onnx_pointer
    from packlab.vlm.candidate.saved import load_pointer

    onnx_model = load_onnx_pointer(SHIPPED)
    settings = PromptSettings.of(onnx_model.meta, blank_map=blank)
    equal, worst = _agreement(load_pointer(SHIPPED), onnx_model, generated, settings)
    assert equal == len(generated)
    assert worst < 1e-4


#: Tiny random pointer models that export: (family, map, line vectors, pool).
TINY_CONFIGS = [
    ("qwen3_vl", "image", True, "last"),
    ("qwen3_vl", "text", False, "mean"),
    ("qwen3_vl", "both", True, "mean"),
    ("qwen2_5_vl", "image", True, "last"),  # no deepstack, 14 px patches
]


def _saved_tiny(tmp_path: Path, family: str, map: str, lines: bool, pool: str):
    """A tiny random pointer model saved as a checkpoint directory (not exported)."""
    torch = _torch()
    from packlab.policies.candidates import ProposerConfig
    from packlab.vlm.candidate.pointer import PointerModel
    from packlab.vlm.candidate.saved import save_pointer
    from packlab.vlm.model.tiny import build_tiny_model
    from packlab.vlm.prompt.render import PROMPT_VERSION

    torch.manual_seed(1)
    model = PointerModel(build_tiny_model(family, "tiny"), pool, map, lines).eval()
    card = {"proposer": asdict(ProposerConfig(k=16)), "instructions": "short", "map": map,
            "line_vectors": lines, "pool": pool, "prompt_version": PROMPT_VERSION}  # fmt: skip
    return model, save_pointer(model, tmp_path / "m", card)


@pytest.mark.torch
@pytest.mark.parametrize(("family", "map", "lines", "pool"), TINY_CONFIGS)
def test_tiny_random_models_export_and_pick_as_torch(generated, tmp_path, family, map, lines, pool):
    _torch()
    from packlab.vlm.candidate.encoding import ImageGrid, PromptSettings
    from packlab.vlm.candidate.onnx_export import export_onnx
    from packlab.vlm.candidate.onnx_scoring import load_onnx_pointer

    model, path = _saved_tiny(tmp_path, family, map, lines, pool)
    exported = export_onnx(path, check_states=4)
    assert exported.extra["check"]["argmax_equal"] == 4
    assert set(exported.graphs) == ({"text"} if map == "text" else {"text", "vision"})
    onnx_model = load_onnx_pointer(path)
    assert onnx_model.grid == ImageGrid.of(model.vlm)  # the card carries the normalisation
    settings = PromptSettings.of(onnx_model.meta)
    equal, worst = _agreement(model, onnx_model, generated, settings)
    assert equal == len(generated) and worst < 1e-4


@pytest.mark.torch
@pytest.mark.parametrize("map", ["image", "text"])
def test_the_last_layer_at_the_lines_alone_scores_bit_for_bit_as_the_whole_layer(
    generated, tmp_path, monkeypatch, map
):
    # The text graph runs its last decoder layer at the listed lines' last tokens only: each
    # score must be the whole layer's to the last bit (so no pick can change), with one listed
    # line and two too.
    _torch()
    import packlab.vlm.candidate.onnx_graphs as graphs
    from packlab.vlm.candidate.encoding import PromptSettings
    from packlab.vlm.candidate.onnx_export import export_onnx
    from packlab.vlm.candidate.onnx_scoring import load_onnx_pointer, score_listed

    model, path = _saved_tiny(tmp_path, "qwen3_vl", map, True, "last")
    assert graphs.TextGraph(model, map == "image").rows_only
    whole = shutil.copytree(path, tmp_path / "whole")
    export_onnx(path, check_states=2)
    monkeypatch.setattr(graphs, "ROWS_ONLY_FAMILIES", ())
    export_onnx(whole, check_states=2)
    rows, full = load_onnx_pointer(path), load_onnx_pointer(whole)
    settings = PromptSettings.of(rows.meta)
    states = [*generated, *((o, listed[:n]) for o, listed in generated[:6] for n in (1, 2))]
    for observation, listed in states:
        np.testing.assert_array_equal(
            score_listed(rows, observation, listed, settings),
            score_listed(full, observation, listed, settings),
        )


@pytest.mark.torch
@pytest.mark.parametrize("family", ["qwen2_5_vl", "qwen3_vl"])
def test_onnx_feeds_the_pixels_torch_normalises(generated, tmp_path, family):
    # The runtime normalises outside the graphs, with the mean and std of the card's grid: the
    # vision graph's input must be the torch path's pixel_values (CLIP's normalisation for
    # Qwen2.5-VL, 0.5 for Qwen3-VL).
    _torch()
    from packlab.vlm.candidate import onnx_scoring, scoring
    from packlab.vlm.candidate.encoding import PromptSettings
    from packlab.vlm.candidate.onnx_export import export_onnx
    from packlab.vlm.candidate.pointer import collate

    model, path = _saved_tiny(tmp_path, family, "image", True, "last")
    grid = export_onnx(path, check_states=2).extra["grid"]
    clip = family == "qwen2_5_vl"
    assert (grid["mean"][0] != 0.5) == clip and (grid["std"][0] != 0.5) == clip
    runtime = onnx_scoring.load_onnx_pointer(path)
    settings = PromptSettings.of(runtime.meta)
    for observation, listed in generated[:4]:
        enc = scoring._encode(model, observation, listed, settings)
        ref = collate([enc], model.vlm.tokenizer.pad_token_id)["pixel_values"].numpy()
        step = onnx_scoring.encode_step(runtime, observation, listed, settings)
        np.testing.assert_array_equal(runtime.grid.pixels(step.image[None])[0], ref)


@needs_export
def test_a_card_without_a_normalisation_reads_as_qwen3s(tmp_path):
    # A card written before the grid carried the normalisation (the shipped one): its model
    # was exported and checked with 0.5.
    from packlab.vlm.candidate.onnx_scoring import load_onnx_pointer

    path = _copy_shipped(tmp_path)
    card = json.loads((path / CARD_FILE).read_text())
    for key in ("mean", "std"):
        card["extra"]["grid"].pop(key, None)
    (path / CARD_FILE).write_text(json.dumps(card))
    grid = load_onnx_pointer(path).grid
    assert grid.mean == grid.std == (0.5, 0.5, 0.5)


@pytest.mark.torch
def test_a_family_that_does_not_export_says_so(tmp_path):
    from packlab.vlm.candidate.onnx_export import export_onnx

    _, path = _saved_tiny(tmp_path, "qwen3_5", "text", False, "last")
    with pytest.raises(ConfigError, match="qwen3_5 pointer model.*runtime=torch"):
        export_onnx(path, check_states=1)
    assert not (path / CARD_FILE).exists()


# -- playing: the default runtime, no torch, the options --------------------------------------


@needs_export
def test_the_default_vlm_plays_onnx_without_importing_torch():
    code = (  # torch, transformers and jinja2 cannot even be imported: as in the core install
        "import sys\n"
        "sys.modules.update(torch=None, transformers=None, jinja2=None)\n"
        "from packlab.cases.load import load_cases\n"
        "from packlab.policies.registry import make_policy\n"
        "from packlab.sim.env import demo_cases_path\n"
        "from packlab.sim.episode import run_episode\n"
        "policy = make_policy('vlm')\n"
        "case = load_cases(demo_cases_path())[0]\n"
        "result = run_episode(case, policy, seed=0, backend='geometric')\n"
        "assert policy.runtime == 'onnx' and policy.decisions == len(result.steps) > 0\n"
        "print(sorted(m for m in ('torch', 'transformers', 'jinja2') if sys.modules.get(m)))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]"


@pytest.mark.torch
@needs_export
def test_both_runtimes_play_the_same_episode():
    from packlab.cases.load import load_cases
    from packlab.sim.env import demo_cases_path
    from packlab.sim.episode import run_episode

    case = load_cases(demo_cases_path())[1]
    runs = {
        rt: run_episode(case, make_policy("vlm", runtime=rt), seed=0, backend="geometric")
        for rt in ("onnx", "torch")
    }
    assert [s.action for s in runs["onnx"].steps] == [s.action for s in runs["torch"].steps]
    assert runs["onnx"].metrics.overall == runs["torch"].metrics.overall


@needs_export
def test_blank_image_plays_under_onnx_and_changes_what_the_model_reads():
    # Checking a flag would pass with blanking ignored. Here the shipped model scores the same
    # listed placements of a state with boxes in it, with its map shown and blanked: the scores
    # must differ (the map is an input), and a blanked episode plays.
    from packlab.cases.load import load_cases
    from packlab.policies.candidates import propose
    from packlab.sim.env import demo_cases_path
    from packlab.sim.episode import Episode, run_episode

    case = load_cases(demo_cases_path())[0]
    episode = Episode("geometric")
    observation = episode.reset(case, 0)
    for _ in range(3):  # a floor with boxes on it
        episode.step(make_policy("sdf").act(observation))
        observation = episode.observe()
    assert observation.heightmap.any()
    shown, blank = make_policy("vlm"), make_policy("vlm", blank_image=True)
    for p in (shown, blank):
        p.load()
    listed = propose(observation, shown._proposer)
    a = shown._score(shown._model, observation, listed, shown._settings)
    b = blank._score(blank._model, observation, listed, blank._settings)
    assert not np.allclose(a, b)
    result = run_episode(case, blank, seed=0, backend="geometric")
    assert blank._settings.blank_map and blank.decisions == len(result.steps)


def test_runtime_names_are_checked():
    with pytest.raises(ConfigError, match="runtime = 'tensorrt'"):
        make_policy("vlm", runtime="tensorrt")


# -- clear errors -----------------------------------------------------------------------------


def _load(path: Path, **kw):
    policy = make_policy("vlm", model=str(path), **kw)
    policy.load()
    return policy


@needs_export
def test_a_directory_without_a_card_says_to_export_it(tmp_path):
    path = _copy_shipped(tmp_path)
    (path / CARD_FILE).unlink()
    with pytest.raises(ConfigError, match=r"packlab export onnx .*runtime=torch"):
        _load(path)


@needs_export
def test_a_missing_graph_is_named(tmp_path):
    path = _copy_shipped(tmp_path)
    (path / "text.onnx").unlink()  # the shipped model reads its map as digits: no vision.onnx
    with pytest.raises(ConfigError, match=r"text\.onnx: ONNX graph missing.*export onnx"):
        _load(path)


@needs_export
def test_another_format_version_is_refused(tmp_path):
    path = _copy_shipped(tmp_path)
    card = json.loads((path / CARD_FILE).read_text())
    (path / CARD_FILE).write_text(json.dumps({**card, "format": "packlab-onnx-0"}))
    with pytest.raises(ConfigError, match=f"'packlab-onnx-0'.*{ONNX_FORMAT}.*export onnx"):
        _load(path)


@needs_export
def test_weights_changed_since_the_export_are_stale(tmp_path):
    path = _copy_shipped(tmp_path)
    head = path / "pointer_head.safetensors"
    head.write_bytes(head.read_bytes() + b" ")
    with pytest.raises(ConfigError, match="pointer_head.safetensors changed.*export onnx"):
        _load(path)


@needs_export
def test_free_json_answers_and_other_templates_need_torch(tmp_path):
    path = _copy_shipped(tmp_path)
    original = (path / "packlab_model.json").read_text()
    meta = json.loads(original)
    (path / "packlab_model.json").write_text(json.dumps({**meta, "answer": "json"}))
    with pytest.raises(ConfigError, match="free JSON.*runtime=torch"):
        _load(path)
    (path / "packlab_model.json").write_text(original)
    (path / "chat_template.jinja").write_text("{{ messages }}")
    with pytest.raises(ConfigError, match="chat template.*runtime=torch"):
        _load(path)
