#!/usr/bin/env bash
# GPU smoke test of the SFT path, as one command: a random-weight model of Qwen3-VL's real
# architecture (vision tower, deepstack, M-RoPE) sized to train in about ten minutes, so that a
# fresh GPU machine shows whether training, checkpointing and closed-loop play run there, how
# fast, and in how much memory, before anyone spends hours on a 9B run.
#
#   bash scripts/gpu_smoke.sh [OUT_DIR]                        (default runs/gpu-smoke)
#   SMOKE_DEVICE=cpu bash scripts/gpu_smoke.sh runs/cpu-smoke    (no GPU: a tiny, quick run)
#
# Needs one CUDA GPU and the vlm extra (pip install torch && pip install -e ".[vlm]");
# SMOKE_DEVICE=cpu runs the same steps on the CPU with a smaller model (fp32), to check the
# script itself on a machine without a GPU.
#
# 1. OUT/model/config.json: a Qwen3-VL config built with transformers.Qwen3VLConfig (so every
#    field the real checkpoints carry is there): text hidden 512, 8 layers, 8 heads (4 KV),
#    head_dim 64; vision depth 4, hidden 256, patch 16; 36 M parameters (the project tokenizer's
#    704-row vocabulary adds almost nothing; a real 152k one would add 155 M). With no
#    tokenizer beside it, --model config:DIR builds it with the project tokenizer and remaps
#    its special token ids to that tokenizer's.
# 2. OUT/data: packlab generate, all three levels, geometric validation (no MuJoCo needed),
#    training seed domain.
# 3. OUT/sft: packlab train sft --max-steps SMOKE_STEPS from random weights, closed-loop play of
#    2 generated cases per level during and after training. Run in-process so that training's
#    peak GPU memory can be read afterwards (torch.cuda.max_memory_allocated).
# 4. OUT/bench: the trained model plays packlab-bench-v1's easy level (seed 0).
# 5. One summary table: throughput, peak memory, first/last loss, Overall. Exit status 1 when a
#    bench episode ended in error.
#
# The cuda defaults are sized for about ten minutes on one H100 in all (an estimate: the SFT
# steps dominate, then the two plays and the bench); scale SMOKE_STEPS to taste.
# Data generation resumes on a rerun; training and the bench start afresh each time, since a
# resumed run's timings would cover only its last part.
#
# Environment (default on cuda [on cpu]):
#   SMOKE_DEVICE       cuda | cpu                                         cuda
#   SMOKE_STEPS        optimizer steps                                    600 [2]
#   SMOKE_GRAD_ACCUM   episodes per optimizer step                        8 [2]
#   SMOKE_EPISODES     generated episodes of easy,medium,hard             150,100,50 [10,6,4]
#   SMOKE_PLAY_EVERY   steps between closed-loop plays (and val losses)   STEPS/2 [STEPS]
#   SMOKE_BENCH_CASES  easy bench cases played (the level has 20)         20 [2]
#   SMOKE_BENCH_SEEDS  bench run seeds                                    0
#   SMOKE_LR           learning rate (random weights need a large one)    1e-3
#   SMOKE_WORKERS      DataLoader workers                                 4 [0]
#   SMOKE_BACKEND      play and bench transition backend                  geometric
#   SMOKE_DATA_SEED    packlab generate --seed                            0
#   SMOKE_HIDDEN, SMOKE_LAYERS, SMOKE_INTERMEDIATE, SMOKE_VISION_DEPTH    512, 8, 1536, 4
#                                                                         [128, 2, 384, 2]
set -euo pipefail

OUT=${1:-runs/gpu-smoke}
DEVICE=${SMOKE_DEVICE:-cuda}
case "$DEVICE" in
    cuda)
        DTYPE=bf16
        VLM_DTYPE=bfloat16
        STEPS=${SMOKE_STEPS:-600}
        EPISODES=${SMOKE_EPISODES:-150,100,50}
        GRAD_ACCUM=${SMOKE_GRAD_ACCUM:-8}
        WORKERS=${SMOKE_WORKERS:-4}
        HIDDEN=${SMOKE_HIDDEN:-512}
        LAYERS=${SMOKE_LAYERS:-8}
        INTERMEDIATE=${SMOKE_INTERMEDIATE:-1536}
        VISION_DEPTH=${SMOKE_VISION_DEPTH:-4}
        PLAY_EVERY=${SMOKE_PLAY_EVERY:-$(( STEPS / 2 > 0 ? STEPS / 2 : 1 ))}
        BENCH_CASES=${SMOKE_BENCH_CASES:-20}
        ;;
    cpu)
        # bf16 matmuls on a CPU are slower than fp32 ones; the point here is the plumbing.
        DTYPE=fp32
        VLM_DTYPE=float32
        STEPS=${SMOKE_STEPS:-2}
        EPISODES=${SMOKE_EPISODES:-10,6,4}
        GRAD_ACCUM=${SMOKE_GRAD_ACCUM:-2}
        WORKERS=${SMOKE_WORKERS:-0}
        HIDDEN=${SMOKE_HIDDEN:-128}
        LAYERS=${SMOKE_LAYERS:-2}
        INTERMEDIATE=${SMOKE_INTERMEDIATE:-384}
        VISION_DEPTH=${SMOKE_VISION_DEPTH:-2}
        # A play of 6 episodes takes minutes on a CPU: play once, at the end.
        PLAY_EVERY=${SMOKE_PLAY_EVERY:-$STEPS}
        BENCH_CASES=${SMOKE_BENCH_CASES:-2}
        ;;
    *)
        echo "SMOKE_DEVICE=$DEVICE: expected cuda or cpu" >&2
        exit 2
        ;;
esac
LR=${SMOKE_LR:-1e-3}
BACKEND=${SMOKE_BACKEND:-geometric}
BENCH_SEEDS=${SMOKE_BENCH_SEEDS:-0}
DATA_SEED=${SMOKE_DATA_SEED:-0}

if [ "$DEVICE" = cuda ]; then
    python -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)" || {
        echo "no CUDA GPU visible to torch; SMOKE_DEVICE=cpu runs the CPU variant" >&2
        exit 2
    }
fi

mkdir -p "$OUT"
echo "== 1/4 model config: Qwen3-VL, hidden $HIDDEN, $LAYERS layers -> $OUT/model" >&2
SMOKE_HIDDEN=$HIDDEN SMOKE_LAYERS=$LAYERS SMOKE_INTERMEDIATE=$INTERMEDIATE \
SMOKE_VISION_DEPTH=$VISION_DEPTH python - "$OUT/model" <<'EOF'
import json
import os
import sys
from pathlib import Path

import torch
from transformers import Qwen3VLConfig, Qwen3VLForConditionalGeneration

from packlab.vlm.model.tiny import mrope_sections
from packlab.vlm.model.tokenizer import build_tokenizer

out = Path(sys.argv[1])
hidden = int(os.environ["SMOKE_HIDDEN"])
layers = int(os.environ["SMOKE_LAYERS"])
depth = int(os.environ["SMOKE_VISION_DEPTH"])
head_dim = 64
heads = hidden // head_dim
# Every project-tokenizer id needs an embedding row; 64-row padding keeps the matmuls aligned.
vocab = -(-len(build_tokenizer()) // 64) * 64
text = {
    "vocab_size": vocab,
    "hidden_size": hidden,
    "intermediate_size": int(os.environ["SMOKE_INTERMEDIATE"]),
    "num_hidden_layers": layers,
    "num_attention_heads": heads,
    "num_key_value_heads": max(1, heads // 2),  # grouped-query attention, as the real models
    "head_dim": head_dim,
    "max_position_embeddings": 32768,
    # Qwen3-VL's interleaved M-RoPE, its (t, h, w) split scaled to this head_dim.
    "rope_parameters": {
        "rope_type": "default",
        "rope_theta": 5_000_000.0,
        "mrope_interleaved": True,
        "mrope_section": mrope_sections(head_dim // 2, (24, 20, 20)),
    },
}
vision = {
    "depth": depth,
    "hidden_size": hidden // 2,
    "intermediate_size": 2 * hidden,
    "num_heads": max(1, hidden // 128),
    "patch_size": 16,
    "spatial_merge_size": 2,
    "temporal_patch_size": 2,
    "out_hidden_size": hidden,
    # Deepstack feeds these vision blocks' features to the first LLM layers; spread them over
    # the tower as the real model does ([8, 16, 24] of 27).
    "deepstack_visual_indexes": sorted({max(0, depth * k // 4 - 1) for k in (1, 2, 3, 4)})[-3:],
}
# The special token ids left at Qwen's defaults are remapped to the project tokenizer's when
# the model is built (build_config_model), as the directory holds no tokenizer.
config = Qwen3VLConfig(text_config=text, vision_config=vision)
config.save_pretrained(out)
with torch.device("meta"):
    n = sum(p.numel() for p in Qwen3VLForConditionalGeneration(config).parameters())
(out / "smoke_params.json").write_text(json.dumps({"parameters": n}) + "\n")
print(f"{out}/config.json: {n / 1e6:.1f} M parameters, vocab {vocab}", file=sys.stderr)
EOF

echo "== 2/4 data: $EPISODES episodes (easy,medium,hard) -> $OUT/data" >&2
packlab generate --difficulty easy,medium,hard --episodes "$EPISODES" --seed "$DATA_SEED" \
    --validation geometric --out "$OUT/data" --no-progress


echo "== 3/4 SFT: $STEPS steps on $DEVICE ($DTYPE) -> $OUT/sft" >&2
rm -rf "$OUT/sft" "$OUT/bench"
# The trainer takes a GPU whenever torch sees one: hiding it is what makes the CPU run a CPU run.
if [ "$DEVICE" = cpu ]; then
    export CUDA_VISIBLE_DEVICES=""
fi
train_args=(train sft --data "$OUT/data" --model "config:$OUT/model" --out "$OUT/sft"
            --dtype "$DTYPE" --lr "$LR" --micro-batch 1 --grad-accum "$GRAD_ACCUM"
            --max-steps "$STEPS" --save-every "$STEPS" --eval-every "$PLAY_EVERY"
            --play-cases 2 --play-every "$PLAY_EVERY" --play-backend "$BACKEND"
            --workers "$WORKERS" --report-to none)
# packlab's own entry point, in this process, so the CUDA allocator's peak is still there to
# read when training returns (nvidia-smi would add the context and the cache's slack).
python - "$OUT/sft/smoke_memory.json" "${train_args[@]}" <<'EOF'
import json
import sys

import torch

from packlab.cli.main import main

code = main(sys.argv[2:])
if code == 0 and torch.cuda.is_available():
    peak = {
        "max_memory_allocated": torch.cuda.max_memory_allocated(),
        "max_memory_reserved": torch.cuda.max_memory_reserved(),
    }
    with open(sys.argv[1], "w") as fh:
        json.dump(peak, fh)
sys.exit(code)
EOF

bench_cases=(--cases packlab-bench-v1 --difficulty easy)
if [ "$BENCH_CASES" -lt 20 ]; then
    # The first cases of the easy level only (a CPU decodes a few answers a second).
    python - "$OUT/bench-easy-$BENCH_CASES.jsonl" "$BENCH_CASES" <<'EOF'
import sys

from packlab.bench.suites import resolve_cases
from packlab.cases.write import save_cases

easy = [c for c in resolve_cases("packlab-bench-v1").cases if c.difficulty == "easy"]
save_cases(easy[: int(sys.argv[2])], sys.argv[1])
EOF
    bench_cases=(--cases "$OUT/bench-easy-$BENCH_CASES.jsonl")
fi
echo "== 4/4 bench: packlab-bench-v1 easy ($BENCH_CASES cases), seeds $BENCH_SEEDS, $DEVICE" >&2
packlab bench "${bench_cases[@]}" --policies vlm --seeds "$BENCH_SEEDS" --backend "$BACKEND" \
    --policy-arg "vlm:model=$OUT/sft/final" --policy-arg "vlm:device=$DEVICE" \
    --policy-arg "vlm:dtype=$VLM_DTYPE" --workers 1 --no-progress --no-figures --no-html \
    --out "$OUT/bench" >&2

python - "$OUT" "$DEVICE" <<'EOF'
import json
import sys
from pathlib import Path

out, device = Path(sys.argv[1]), sys.argv[2]
log = [json.loads(ln) for ln in (out / "sft" / "loss_log.jsonl").read_text().splitlines()]
summary = json.loads((out / "sft" / "sft_summary.json").read_text())
params = json.loads((out / "model" / "smoke_params.json").read_text())["parameters"]
bench = json.loads((out / "bench" / "summary.json").read_text())
memory = out / "sft" / "smoke_memory.json"

losses = [r["loss"] for r in log if "loss" in r]
tokens = max(r["num_tokens"] for r in log if "num_tokens" in r)
end = next(i for i, r in enumerate(log) if "train_runtime" in r)
runtime = log[end]["train_runtime"]
# Plays and validation passes run inside the training loop; their time is not training's.
aside = sum(r.get("play_s", 0.0) + r.get("eval_runtime", 0.0) for r in log[:end])
train_s = max(runtime - aside, 1e-9)
plays = [r for r in log if "play_overall" in r]
if memory.is_file():
    peak = json.loads(memory.read_text())
    mem = f"{peak['max_memory_allocated'] / 2**30:.2f} GiB allocated, " \
          f"{peak['max_memory_reserved'] / 2**30:.2f} GiB reserved"
else:
    mem = "n/a (no GPU)"
counts = bench["counts"]["vlm"]
overall = bench["table"]["vlm"]["easy"]["overall"]["mean"]
rows = [
    ("device", device),
    ("model", f"Qwen3-VL config, {params / 1e6:.1f} M parameters, {summary['dtype']}"),
    ("optimizer steps", f"{summary['optimizer_steps']} x {summary['global_batch']} episodes"),
    ("train examples", f"{summary['train_examples']} episodes, max length {summary['max_length']}"),
    ("tokens/s (train)", f"{tokens / train_s:,.0f} ({tokens:,.0f} tokens in {train_s:.1f} s; "
                         f"train_runtime {runtime:.1f} s less {aside:.1f} s of play and eval)"),
    ("peak GPU memory", mem),
    ("loss first -> last", f"{losses[0]:.4f} -> {losses[-1]:.4f}"),
    ("play Overall (last)", f"{plays[-1]['play_overall']:.3f} over {plays[-1]['play_episodes']} "
                            f"generated cases, {plays[-1]['play_parsed']:.0%} answers parsed"
                            if plays else "n/a"),
    ("bench easy Overall", f"{overall:.3f} over {counts['episodes']} episodes "
                           f"({counts['errors']} errors, {counts['invalid_steps']} of "
                           f"{counts['steps']} steps invalid, {counts['decision_ms']:.0f} ms "
                           "per decision)"),
]
width = max(len(k) for k, _ in rows)
print(f"\n| {'gpu smoke':<{width}} | {out} |")
print(f"| {'-' * width} | {'-' * len(str(out))} |")
for k, v in rows:
    print(f"| {k:<{width}} | {v} |")
# A smoke test passes only if every bench episode ran (a zero Overall is a fine first result).
sys.exit(1 if counts["errors"] else 0)
EOF
