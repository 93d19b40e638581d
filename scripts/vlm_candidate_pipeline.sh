#!/usr/bin/env bash
# Reproduce the shipped candidate-mode vlm-small (docs/vlm.md): training cases -> teacher
# rollouts + one DAgger round -> pointer model -> bench. Every step resumes when rerun.
#   bash scripts/vlm_candidate_pipeline.sh [OUT_DIR]        (default runs/vlm-cand)
set -euo pipefail
OUT=${1:-runs/vlm-cand}
packlab generate --difficulty easy,medium,hard --episodes 500,500,500 --seed 9001 \
    --validation geometric --sft none --out "$OUT/cases"
packlab train candidate --cases "$OUT/cases" --out "$OUT" --teacher plan --rounds 1 \
    --cases-per-round 450 --steps 2000 --round-steps 1500 --minutes-per-round 45 --threads 1
packlab bench --policies vlm,proposer,sdf --policy-arg "vlm:model=$OUT/final" \
    --out "$OUT/bench"
