"""SFT smoke test: a few optimizer steps on a tiny batch reduce the answer loss (CPU, tiny)."""

from __future__ import annotations

import json

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")
pytest.importorskip("accelerate")

from PIL import Image

from packlab.core.errors import ConfigError
from packlab.core.types import Action
from packlab.viz.plots import plot_loss_curve
from packlab.vlm.data.sft_examples import load_sft_examples, select_examples
from packlab.vlm.model.checkpoint import load_model
from packlab.vlm.prompt.render import PROMPT_VERSION, render_messages, with_answer
from packlab.vlm.train.config import SFTConfig
from packlab.vlm.train.sft import train_sft

pytestmark = pytest.mark.torch


def _write_dataset(root, fixed_state):
    """A two-example SFT export in the documented format, with real PNGs under images/."""
    container, past, current = fixed_state
    (root / "images" / "ep0").mkdir(parents=True)
    (root / "meta").mkdir()
    (root / "meta" / "info.json").write_text("{}")
    for i, shade in enumerate((40, 120, 200)):
        Image.new("RGB", (224, 224), (shade, 255 - shade, 90)).save(
            root / f"images/ep0/step{i}.png"
        )
    rows = [
        {
            "messages": with_answer(render_messages(container, [], past[0][0]), Action(0, 0, 0, 0)),
            "episode_id": "easy-0",
            "difficulty": "easy",
            "step_index": 0,
            "prompt_version": PROMPT_VERSION,
        },
        {
            "messages": with_answer(render_messages(container, past, current), Action(1, 1, 6, 2)),
            "episode_id": "medium-1",
            "difficulty": "medium",
            "step_index": 2,
            "prompt_version": PROMPT_VERSION,
        },
    ]
    (root / "sft").mkdir()
    (root / "sft" / "train.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return root


def test_few_steps_reduce_loss(fixed_state, tmp_path):
    data = _write_dataset(tmp_path / "data", fixed_state)
    cfg = SFTConfig(
        data=str(data),
        out=str(tmp_path / "run"),
        model="tiny:qwen3_5:tiny",
        epochs=6,
        micro_batch=2,
        grad_accum=1,
        lr=3e-3,
        warmup_ratio=0.0,
        history="current_only",
    )
    res = train_sft(cfg, progress=False)
    assert res.optimizer_steps == 6 and res.n_examples == 2
    assert all(b < a for a, b in zip(res.losses, res.losses[1:])), res.losses
    assert res.losses[-1] < res.losses[0] - 1.0, res.losses
    run = tmp_path / "run"
    resolved = json.loads((run / "sft_config.json").read_text())
    assert resolved["prompt_version"] == PROMPT_VERSION and resolved["lr"] == 3e-3
    assert len((run / "loss_log.jsonl").read_text().splitlines()) == 6
    assert not (run / "loss_curve.png").exists()  # vlm draws nothing; the CLI plots the log
    plot_loss_curve(res.loss_log, run / "loss_curve.png")
    assert (run / "loss_curve.png").stat().st_size > 1000
    assert (run / "checkpoints" / "epoch-1" / "config.json").is_file()
    loaded = load_model(res.final_checkpoint)
    assert loaded.meta["sft_config"]["model"] == "tiny:qwen3_5:tiny"
    assert loaded.meta["prompt_version"] == PROMPT_VERSION


def test_lora_trains_and_merges(fixed_state, tmp_path):
    pytest.importorskip("peft")
    data = _write_dataset(tmp_path / "data", fixed_state)
    cfg = SFTConfig(
        data=str(data),
        out=str(tmp_path / "run"),
        model="tiny:qwen3_vl:tiny",
        epochs=3,
        micro_batch=2,
        grad_accum=1,
        lr=1e-2,
        warmup_ratio=0.0,
        lora=True,
        lora_r=4,
        history="current_only",
        image="none",
        gradient_checkpointing=True,
    )
    res = train_sft(cfg, progress=False)
    assert res.losses[-1] < res.losses[0]
    loaded = load_model(res.final_checkpoint)  # merged: a plain model, no peft needed to read it
    assert not any("lora" in n for n, _ in loaded.model.named_parameters())


def test_data_controls(fixed_state, tmp_path):
    data = _write_dataset(tmp_path / "data", fixed_state)
    examples, root = load_sft_examples(data)
    assert root == data and len(examples) == 2
    assert examples[1].answer == '{"object_id":1,"rotation":1,"x":6,"y":2}'
    assert [e.episode_id for e in select_examples(examples, "easy")] == ["easy-0"]
    assert len(select_examples(examples, "easy+medium")) == 2
    assert len(select_examples(examples, "mixed", data_fraction=0.5, seed=3)) == 1
    with pytest.raises(ConfigError, match="recipe"):
        select_examples(examples, "hard-only")


def test_config_validated():
    with pytest.raises(ConfigError, match="history"):
        SFTConfig(data="d", out="o", history="everything")
    with pytest.raises(ConfigError, match="data_fraction"):
        SFTConfig(data="d", out="o", data_fraction=0.0)
    assert SFTConfig(data="d", out="o").resolved_lr == 1e-3
    assert SFTConfig(data="d", out="o", model="/ckpt").resolved_lr == 1e-5


@pytest.mark.slow
def test_two_process_cpu_run(fixed_state, tmp_path):
    """The multi-process path (what FSDP/DDP on GPUs uses): 2 ranks on CPU over gloo, launched
    with torchrun. Each rank sees half the data, the schedule is laid out over the steps every
    rank really takes, only rank 0 writes and reports."""
    import os
    import subprocess
    import sys

    data = _write_dataset(tmp_path / "data", fixed_state)
    run = tmp_path / "run"
    env = dict(os.environ, ACCELERATE_USE_CPU="true", OMP_NUM_THREADS="1")
    cmd = [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
        "-m", "packlab.cli.main", "train", "sft", "--data", str(data), "--out", str(run),
        "--model", "tiny:qwen3_vl:tiny", "--epochs", "3", "--max-steps", "2",
        "--micro-batch", "1", "--grad-accum", "1", "--lr", "1e-3", "--warmup-ratio", "0",
        "--history", "current_only",
    ]  # fmt: skip
    proc = subprocess.run(cmd, check=False, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.count("trained 2 steps") == 1, proc.stdout
    resolved = json.loads((run / "sft_config.json").read_text())
    assert resolved["devices"] == 2 and resolved["global_batch"] == 2
    assert resolved["updates_per_epoch"] == 1 and resolved["total_updates"] == 2
    lrs = [json.loads(line)["lr"] for line in (run / "loss_log.jsonl").read_text().splitlines()]
    # cosine over 2 steps: half-way after the first, zero after the last (not restarted)
    assert lrs == pytest.approx([5e-4, 0.0], abs=1e-9)
    assert (run / "loss_curve.png").stat().st_size > 1000  # drawn by the command
    assert load_model(run / "final").meta["prompt_version"] == PROMPT_VERSION
