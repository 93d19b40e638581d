#!/usr/bin/env bash
# The "model trained here" run of the VLM issue, as one command:
#
#   bash scripts/vlm_small_pipeline.sh [OUT_DIR]        (default runs/vlm-small)
#
# 1. generate a PackData subset with the data engine (training seed space, disjoint from the bench);
# 2. supervised fine-tuning of a tiny-family model from random weights (loss on every answer);
# 3. evaluate it on packlab-bench-v1 with the bench runner (3 seeds, mujoco), then the paper's
#    ablations (blank image, current step only, no past actions), each in its own run directory.
#
# Every step is resumable: rerunning the same command skips finished dataset shards and bench
# episodes, and training continues from its last checkpoint. Sizes are environment variables so a quick try and
# the full run use the same script:
#
#   EPISODES=60,40,20 EPOCHS=1 MAX_STEPS=20 bash scripts/vlm_small_pipeline.sh runs/vlm-try
#
# Needs the vlm extra: pip install torch==2.13.0 && pip install -e ".[vlm]"
set -euo pipefail

OUT=${1:-runs/vlm-small}
EPISODES=${EPISODES:-550,275,90}           # easy,medium,hard trajectories (one conversation each)
DATA_SEED=${DATA_SEED:-7}
MODEL=${MODEL:-tiny:qwen3_vl:small}         # family:size of the random-weight model
EPOCHS=${EPOCHS:-1}
MAX_STEPS=${MAX_STEPS:-}                    # optimizer steps (x8 episodes); empty: EPOCHS passes
GRAD_ACCUM=${GRAD_ACCUM:-8}
SEEDS=${SEEDS:-0,1,2}
DIFFICULTY=${DIFFICULTY:-}                  # e.g. easy to evaluate on one level only

mkdir -p "$OUT"
echo "== 1/3 data: $EPISODES episodes -> $OUT/data" >&2
packlab generate --difficulty easy,medium,hard --episodes "$EPISODES" --seed "$DATA_SEED" \
    --out "$OUT/data"

echo "== 2/3 SFT: $MODEL, $EPOCHS epoch(s) -> $OUT/sft" >&2
train_args=(--data "$OUT/data" --model "$MODEL" --out "$OUT/sft" --epochs "$EPOCHS"
            --grad-accum "$GRAD_ACCUM")
[ -n "$MAX_STEPS" ] && train_args+=(--max-steps "$MAX_STEPS")
if [ ! -f "$OUT/sft/final/packlab_model.json" ]; then
    packlab train sft "${train_args[@]}"
fi

echo "== 3/3 bench: packlab-bench-v1, seeds $SEEDS" >&2
bench_args=(--policies vlm --seeds "$SEEDS" --no-figures)
[ -n "$DIFFICULTY" ] && bench_args+=(--difficulty "$DIFFICULTY")
model_arg="vlm:model=$OUT/sft/final"
packlab bench "${bench_args[@]}" --policy-arg "$model_arg" --out "$OUT/bench-full"
packlab bench "${bench_args[@]}" --policy-arg "$model_arg" --policy-arg vlm:image=blank --out "$OUT/bench-blank-image"
packlab bench "${bench_args[@]}" --policy-arg "$model_arg" --policy-arg vlm:history=current_only --out "$OUT/bench-current-only"
packlab bench "${bench_args[@]}" --policy-arg "$model_arg" --policy-arg vlm:history=no_actions --out "$OUT/bench-no-actions"

packlab bench compare "$OUT/bench-full" "$OUT/bench-blank-image" "$OUT/bench-current-only" \
    "$OUT/bench-no-actions" --labels "full context,blank image,current step only,no past actions" \
    --out "$OUT/ablations.md"

echo "== done: loss curve $OUT/sft/loss_curve.png; tables $OUT/bench-*/table.md, $OUT/ablations.md" >&2
