"""SFT on TRL with tiny models on CPU: labels, loss, resume, multi-process, exports, errors."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")
pytest.importorskip("trl")
datasets = pytest.importorskip("datasets")

from packlab.core.errors import ConfigError
from packlab.datagen.config import DatasetConfig, ValidationConfig
from packlab.datagen.engine import RunOptions, generate_dataset
from packlab.vlm.data.sft_dataset import ablate_conversation, load_sft_data
from packlab.vlm.model.checkpoint import load_model
from packlab.vlm.model.processor import processor_for
from packlab.vlm.model.tiny import build_tiny_model
from packlab.vlm.prompt.render import PROMPT_VERSION, PromptOptions
from packlab.vlm.train.config import SFTConfig
from packlab.vlm.train.sft import LOSS_LOG, train_sft

pytestmark = pytest.mark.torch


@pytest.fixture(scope="module")
def sft_data(tmp_path_factory) -> Path:
    """Six short episodes (easy and medium), 64 px images, the hf export under sft/."""
    out = tmp_path_factory.mktemp("sft") / "data"
    cfg = DatasetConfig(
        difficulties=("easy", "medium"),
        episodes=(4, 2),
        seed=11,
        shard_size=3,
        image_size=64,
        validation=ValidationConfig(backend="geometric"),
    )
    generate_dataset(cfg, RunOptions(str(out), workers=1, progress=False))
    return out


def _cfg(data: Path, out: Path, **kw) -> SFTConfig:
    base = {
        "data": str(data),
        "out": str(out),
        "model": "tiny:qwen3_vl:tiny",
        "micro_batch": 1,
        "grad_accum": 2,
        "lr": 3e-3,
        "warmup_ratio": 0.0,
        "val_fraction": 0.0,
        "report_to": "none",
        "save_every": 1000,
        "eval_every": 1000,
    }
    base.update(kw)
    return SFTConfig(**base)


def _collate(vlm, rows):
    from trl.trainer.sft_trainer import DataCollatorForVisionLanguageModeling

    processor = processor_for(vlm)
    collator = DataCollatorForVisionLanguageModeling(processor, assistant_only_loss=True)
    return collator([{"messages": r["messages"], "images": r["images"]} for r in rows])


@pytest.mark.parametrize("family", ["qwen3_5", "qwen3_vl", "qwen2_5_vl"])
def test_only_assistant_tokens_carry_labels(sft_data, family):
    """Token by token: the labelled tokens are exactly each answer and its <|im_end|>, each
    right after an assistant header, and nothing else (system, user, images, padding)."""
    vlm = build_tiny_model(family, "tiny")
    rows = [load_sft_data(sft_data).train[i] for i in range(2)]
    batch = _collate(vlm, rows)
    tok = vlm.tokenizer
    im_end = tok.convert_tokens_to_ids("<|im_end|>")
    header = tok("<|im_start|>assistant\n", add_special_tokens=False)["input_ids"]
    for b, row in enumerate(rows):
        ids, labels = batch["input_ids"][b].tolist(), batch["labels"][b].tolist()
        answers = [m["content"][0]["text"] for m in row["messages"] if m["role"] == "assistant"]
        expected = []
        for a in answers:
            expected += tok(a, add_special_tokens=False)["input_ids"] + [im_end]
        labelled = [t for t, lab in zip(ids, labels) if lab != -100]
        assert labelled == expected
        assert all(lab in (-100, t) for t, lab in zip(ids, labels))
        starts = [i for i in range(len(ids)) if labels[i] != -100 and labels[i - 1] == -100]
        assert len(starts) == len(answers)
        for s in starts:
            assert ids[s - len(header) : s] == header


def test_training_tokens_match_the_inference_encoding(sft_data):
    """The collator's tokens for a context are those the inference encoder gives it."""
    from packlab.vlm.data.encoding import encode

    vlm = build_tiny_model("qwen3_vl", "tiny")
    row = load_sft_data(sft_data).train[0]
    images = iter(row["images"])
    context = [
        dict(m, content=[dict(c, image=next(images)) if c["type"] == "image" else c
                         for c in m["content"]])
        for m in row["messages"][:-1]
    ]  # fmt: skip
    prompt = encode(context, vlm.tokenizer, vlm.image_processor).input_ids.tolist()
    batch = _collate(vlm, [row])
    ids = batch["input_ids"][0].tolist()
    assert ids[: len(prompt)] == prompt


def _turn_losses(model, batch):
    """Mean NLL of each labelled run (one per assistant turn)."""
    with torch.no_grad():
        logits = model(**{k: v for k, v in batch.items() if k != "labels"}).logits[0, :-1]
    labels = batch["labels"][0, 1:]
    nll = torch.nn.functional.cross_entropy(logits.float(), labels.clamp(min=0), reduction="none")
    runs, cur = [], []
    for i, lab in enumerate(labels.tolist()):
        if lab != -100:
            cur.append(float(nll[i]))
        elif cur:
            runs.append(sum(cur) / len(cur))
            cur = []
    if cur:
        runs.append(sum(cur) / len(cur))
    return runs


def test_loss_falls_on_every_assistant_turn(sft_data, tmp_path):
    cfg = _cfg(sft_data, tmp_path / "run", max_steps=12, recipe="easy")
    rows = [load_sft_data(sft_data, recipe="easy").train[0]]
    vlm = build_tiny_model("qwen3_vl", "tiny")
    batch = _collate(vlm, rows)
    before = _turn_losses(vlm.model.eval(), batch)
    res = train_sft(cfg, progress=False)
    after = _turn_losses(load_model(res.final_checkpoint).model, batch)
    assert len(before) == len(after) == rows[0]["n_steps"] >= 3
    assert all(a < b for a, b in zip(after, before)), (before, after)
    assert res.losses[-1] < res.losses[0]
    meta = json.loads((res.final_checkpoint / "packlab_model.json").read_text())
    assert meta["prompt_version"] == PROMPT_VERSION and meta["sft_config"]["model"] == cfg.model
    assert (res.out / "sft_summary.json").is_file()


def _losses(out: Path) -> list[tuple[int, float]]:
    lines = [json.loads(x) for x in (out / LOSS_LOG).read_text().splitlines()]
    return [(x["step"], x["loss"]) for x in lines if "loss" in x]


def test_stop_and_resume_continues_exactly(sft_data, tmp_path):
    """A run resumed from its checkpoint logs the same losses as the run that never stopped
    (optimizer, scheduler, RNG and data position restored)."""
    cfg = _cfg(sft_data, tmp_path / "run", max_steps=4, save_every=2, epochs=2)
    full = train_sft(cfg, progress=False)
    uninterrupted = _losses(full.out)
    assert [s for s, _ in uninterrupted] == [1, 2, 3, 4]
    # As if killed after the checkpoint at step 2: the later checkpoint and model never written.
    shutil.rmtree(full.out / "checkpoint-4")
    shutil.rmtree(full.out / "final")
    resumed = train_sft(cfg, progress=False)
    assert resumed.resumed_from is not None and resumed.resumed_from.endswith("checkpoint-2")
    assert _losses(resumed.out) == uninterrupted


def test_resume_with_other_settings_is_refused(sft_data, tmp_path):
    cfg = _cfg(sft_data, tmp_path / "run", max_steps=2, save_every=1)
    train_sft(cfg, progress=False)
    with pytest.raises(ConfigError, match=r"lr: 0.003 -> 0.01"):
        train_sft(_cfg(sft_data, tmp_path / "run", max_steps=2, save_every=1, lr=1e-2))


def test_lora_trains_and_merges(sft_data, tmp_path):
    cfg = _cfg(sft_data, tmp_path / "run", max_steps=3, lora=True, lora_r=4)
    res = train_sft(cfg, progress=False)
    merged = load_model(res.final_checkpoint)
    base = build_tiny_model("qwen3_vl", "tiny")
    names = [n for n, _ in merged.model.named_parameters()]
    assert not any("lora" in n for n in names)
    changed = [
        n
        for (n, p), (_, q) in zip(merged.model.named_parameters(), base.model.named_parameters())
        if not torch.equal(p, q)
    ]
    assert changed and all("language_model" in n for n in changed)  # the vision tower is frozen
    assert (res.out / "adapter" / "adapter_config.json").is_file()


def test_full_finetuning_keeps_the_vision_tower_unless_asked(sft_data, tmp_path):
    res = train_sft(_cfg(sft_data, tmp_path / "a", max_steps=2), progress=False)
    base = build_tiny_model("qwen3_vl", "tiny").model.state_dict()
    tuned = load_model(res.final_checkpoint).model.state_dict()
    assert all(torch.equal(tuned[k], base[k]) for k in base if "visual" in k)
    res = train_sft(_cfg(sft_data, tmp_path / "b", max_steps=2, train_vision=True), False)
    tuned = load_model(res.final_checkpoint).model.state_dict()
    assert any(not torch.equal(tuned[k], base[k]) for k in base if "visual" in k)


def test_validation_split_is_by_episode_and_logged(sft_data, tmp_path):
    cfg = _cfg(sft_data, tmp_path / "run", max_steps=2, val_fraction=0.3, eval_every=1)
    data = load_sft_data(sft_data, val_fraction=0.3)
    assert not set(data.train["episode_id"]) & set(data.val["episode_id"])
    res = train_sft(cfg, progress=False)
    lines = [json.loads(x) for x in (res.out / LOSS_LOG).read_text().splitlines()]
    assert [x["step"] for x in lines if "eval_loss" in x] == [1, 2]


def test_closed_loop_play_is_logged(sft_data, tmp_path):
    from packlab.cli.train_run import play_cases

    cfg = _cfg(sft_data, tmp_path / "run", max_steps=2, play_cases=1, play_every=2)
    res = train_sft(cfg, play_cases=play_cases(1, cfg.play_seed)[:2], progress=False)
    lines = [json.loads(x) for x in (res.out / LOSS_LOG).read_text().splitlines()]
    played = [x for x in lines if "play_overall" in x]
    assert len(played) == 1 and played[0]["step"] == 2 and played[0]["play_episodes"] == 2
    assert 0.0 <= played[0]["play_overall"] <= 1.0


def test_hf_export_feeds_trl_sfttrainer_directly(sft_data, tmp_path):
    """No packlab code between the files and TRL: load_dataset, then SFTTrainer."""
    from trl import SFTConfig as TRLConfig
    from trl import SFTTrainer

    ds = datasets.load_dataset(str(sft_data), "sft", split="train")
    vlm = build_tiny_model("qwen3_5", "tiny")
    args = TRLConfig(
        output_dir=str(tmp_path / "trl"),
        max_steps=2,
        per_device_train_batch_size=2,
        assistant_only_loss=True,
        report_to=[],
        use_cpu=True,
        save_strategy="no",
        activation_checkpointing=False,  # TRL turns it on by default; tiny models do not need it
        max_length=None,  # TRL's default (1024) would cut conversations inside an image
    )
    trainer = SFTTrainer(
        model=vlm.model, args=args, train_dataset=ds, processing_class=processor_for(vlm)
    )
    out = trainer.train()
    assert out.global_step == 2 and out.training_loss > 0


def test_history_ablations_expand_to_one_example_per_step(sft_data):
    row = load_sft_data(sft_data).train[0]
    n = row["n_steps"]
    full = ablate_conversation(row["messages"], row["images"], PromptOptions())
    assert len(full) == 1 and len(full[0]["images"]) == n
    current = ablate_conversation(row["messages"], row["images"], PromptOptions("current_only"))
    assert len(current) == n
    for i, ex in enumerate(current):
        assert [m["role"] for m in ex["messages"]] == ["system", "user", "assistant"]
        assert len(ex["images"]) == 1 and ex["images"][0] == row["images"][i]
    blank = ablate_conversation(row["messages"], row["images"], PromptOptions(image="blank"))
    assert all(not im.getbbox() for im in blank[0]["images"])  # all black
    none = ablate_conversation(row["messages"], row["images"], PromptOptions(image="none"))
    assert none[0]["images"] == []


def test_too_long_examples_stop_before_training(sft_data, tmp_path):
    cfg = _cfg(sft_data, tmp_path / "run", max_length=64)
    with pytest.raises(ConfigError, match=r"max_length = 64: \d+ example\(s\) are longer"):
        train_sft(cfg, progress=False)
    assert not (tmp_path / "run").exists()
    res = train_sft(
        _cfg(sft_data, tmp_path / "run", max_length=900, truncation="drop", max_steps=1), False
    )
    summary = json.loads((res.out / "sft_summary.json").read_text())
    assert res.dropped_examples == summary["dropped_for_length"] > 0


def _run_cli(*args, env=None):
    return subprocess.run(
        [sys.executable, "-m", "packlab.cli.main", *args],
        check=False,
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )


def test_cli_errors_are_one_line_and_keep_the_run(sft_data, tmp_path):
    run = tmp_path / "run"
    train_sft(_cfg(sft_data, run, max_steps=2, save_every=1), progress=False)
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    proc = _run_cli(
        "train", "sft", "--data", str(sft_data), "--out", str(tmp_path / "new"),
        "--model", "tiny:qwen3_vl:tiny", "--max-length", "64",
    )  # fmt: skip
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0, proc.stderr
    assert "max_length = 64" in proc.stderr and not (tmp_path / "new").exists()
    proc = _run_cli(
        "train", "sft", "--data", str(sft_data), "--out", str(run),
        "--model", "tiny:qwen3_vl:tiny", "--lr", "0.5", "--report-to", "none",
    )  # fmt: skip
    assert proc.returncode == 2 and "resuming" in proc.stderr, proc.stderr
    assert sorted(p.relative_to(run) for p in run.rglob("*")) == before
    jsonl = tmp_path / "old"
    (jsonl / "sft").mkdir(parents=True)
    (jsonl / "sft" / "a.jsonl").write_text("{}\n")
    proc = _run_cli("train", "sft", "--data", str(jsonl), "--out", str(tmp_path / "x"))
    assert proc.returncode == 2 and "packlab export sft" in proc.stderr


@pytest.mark.slow
def test_two_gloo_processes_match_one_with_the_same_global_batch(sft_data, tmp_path):
    """2 ranks x 1 episode (gloo, torchrun) take the same update as 1 rank x 2 accumulated."""
    common = [
        "train", "sft", "--data", str(sft_data), "--model", "tiny:qwen3_vl:tiny",
        "--max-steps", "2", "--micro-batch", "1", "--lr", "3e-3", "--warmup-ratio", "0",
        "--val-fraction", "0", "--report-to", "none", "--seed", "3",
    ]  # fmt: skip
    env = dict(os.environ, OMP_NUM_THREADS="1")
    one = _run_cli(*common, "--grad-accum", "2", "--out", str(tmp_path / "one"), env=env)
    assert one.returncode == 0, one.stderr[-3000:]
    cmd = [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
        "-m", "packlab.cli.main", *common, "--grad-accum", "1", "--out", str(tmp_path / "two"),
    ]  # fmt: skip
    two = subprocess.run(cmd, check=False, env=env, capture_output=True, text=True, timeout=900)
    assert two.returncode == 0, two.stderr[-3000:]
    assert two.stdout.count("trained 2 steps") == 1  # rank 0 reports
    resolved = json.loads((tmp_path / "two" / "sft_config.json").read_text())
    assert resolved["devices"] == 2 and resolved["global_batch"] == 2
    a = load_model(tmp_path / "one" / "final").model.state_dict()
    b = load_model(tmp_path / "two" / "final").model.state_dict()
    worst = max(float((a[k] - b[k]).abs().max()) for k in a)
    assert worst < 1e-4, worst


def test_training_template_renders_what_the_inference_template_renders(sft_data):
    from packlab.vlm.model.chatml import CHAT_TEMPLATE, TRAINING_CHAT_TEMPLATE, render_chat

    tok = build_tiny_model("qwen3_5", "tiny").tokenizer
    row = load_sft_data(sft_data).train[0]
    msgs = row["messages"]
    for n in (2, 3, len(msgs)):
        for gen in (True, False):
            a = tok.apply_chat_template(msgs[:n], chat_template=CHAT_TEMPLATE, tokenize=False,
                                        add_generation_prompt=gen)  # fmt: skip
            b = tok.apply_chat_template(msgs[:n], chat_template=TRAINING_CHAT_TEMPLATE,
                                        tokenize=False, add_generation_prompt=gen)  # fmt: skip
            assert a == b == render_chat(msgs[:n], add_generation_prompt=gen)


@pytest.mark.parametrize("family", ["qwen3_5", "qwen2_5_vl"])
def test_the_processor_pickles_for_dataloader_workers(family):
    import pickle

    processor = processor_for(build_tiny_model(family, "tiny"))
    again = pickle.loads(pickle.dumps(processor))
    assert type(again) is type(processor) and again.chat_template == processor.chat_template


def test_dataloader_workers_train_the_same_as_the_main_process(sft_data, tmp_path):
    a = train_sft(_cfg(sft_data, tmp_path / "a", max_steps=2), progress=False)
    b = train_sft(_cfg(sft_data, tmp_path / "b", max_steps=2, workers=1), progress=False)
    steps_a, losses_a = zip(*_losses(a.out))
    steps_b, losses_b = zip(*_losses(b.out))
    assert steps_a == steps_b and losses_a == pytest.approx(losses_b, abs=1e-6)
