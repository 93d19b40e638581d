#!/usr/bin/env bash
# The shipped learned policies of issue 36, end to end on a 2-core CPU (about 3.9 hours in all:
# 2.5 for steps 1-6, 80 min for step 7; every step resumes when rerun). Sides are named longer
# first (the default), so no model can learn the catalogue's orientation hint. Cases: generated
# in the train seed domain (ids carry their seed), never a bench suite; every case file and state
# row is checked by content.
set -euo pipefail
OUT=${OUT:-runs/student}
mkdir -p "$OUT"
export OMP_NUM_THREADS=1
cases() {  # FILE PER_LEVEL SEED: generated cases (train seed domain, geometric plan checks)
  [ -f "$1" ] || python - "$@" <<'PY'
import sys
from packlab.cases.write import save_cases
from packlab.datagen import generate_cases
path, n, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
save_cases([c for lv in ("easy", "medium", "hard")
            for c in generate_cases(lv, n, seed, False, domain="train")], path)
PY
}
cases "$OUT/train-r0.jsonl" 200 3601
cases "$OUT/train-r1.jsonl" 200 3610
cases "$OUT/train-r2.jsonl" 200 3602
for s in 3 4 5; do cases "$OUT/train-r$s.jsonl" 200 360$s; done
cases "$OUT/heldout.jsonl" 20 3609   # the selection set (60 cases): never trained on
cat "$OUT"/train-r{0,1,2,3,4,5}.jsonl > "$OUT/train-all.jsonl"
collect() { python scripts/collect_states.py "$@"; }

# 1. Round 0: the planner's own trajectories on 600 cases, every state labelled (K = 16, soft
#    targets); both agents fitted to them by imitation.
collect "$OUT/train-r0.jsonl" "$OUT/r0-states.jsonl" r0
packlab train rl-imitate --agent irbpp --states "$OUT/r0-states.jsonl" \
    --cases "$OUT/train-r0.jsonl" --out "$OUT/irbpp-im0" --epochs 30 --seed 0
packlab train rl-imitate --agent tapnet --placement dblf --states "$OUT/r0-states.jsonl" \
    --cases "$OUT/train-r0.jsonl" --out "$OUT/tapnet-im0" --epochs 30 --seed 0

# 2. DAgger round 1: each student plays 600 new cases and the planner labels every state it
#    reaches (about 12 min each on one core).
collect "$OUT/train-r1.jsonl" "$OUT/r1-irbpp.jsonl" r1-irbpp --workers 1 \
    --actor irbpp --actor-opts "{\"model\": \"$OUT/irbpp-im0\"}"
collect "$OUT/train-r2.jsonl" "$OUT/r1-tapnet.jsonl" r1-tapnet --workers 1 \
    --actor tapnet --actor-opts "{\"model\": \"$OUT/tapnet-im0\"}"
cat "$OUT/r0-states.jsonl" "$OUT/r1-irbpp.jsonl" "$OUT/r1-tapnet.jsonl" > "$OUT/s-r01.jsonl"

# 3. irbpp: MaskablePPO from the round-0 imitation (refitting on rounds 0 + 1 scored the same on
#    the held-out set, 0.847 vs 0.849), 60 min on the training cases.
packlab train rl --agent irbpp --init "$OUT/irbpp-im0" --cases "$OUT/train-all.jsonl" \
    --lr 0.0001 --ent-coef 0.001 --minutes 60 --envs 4 --vec dummy --eval-every 10000 \
    --seed 0 --out "$OUT/irbpp-ppo0"

# 4. tapnet: the box chosen by the agent, placed at the proposer's first listing of it
#    (--placement proposer, the default); imitation of rounds 0 + 1, then MaskablePPO.
packlab train rl-imitate --agent tapnet --placement proposer --states "$OUT/s-r01.jsonl" \
    --out "$OUT/tapnet-im1p" --epochs 30 --seed 0
packlab train rl --agent tapnet --placement proposer --init "$OUT/tapnet-im1p" \
    --cases "$OUT/train-all.jsonl" --lr 0.0001 --ent-coef 0.001 --minutes 30 --envs 4 \
    --vec dummy --eval-every 10000 --seed 0 --out "$OUT/tapnet-ppo0"

# 5. vlm-small: the pointer model with the heightmap as a digit map (no vision tower), trained
#    from random weights on rounds 0 + 1 (40 min cap on one thread).
python scripts/vlm_continue.py --model tiny:qwen3_vl:mini --map text \
    --states "$OUT/s-r01.jsonl" --cases "$OUT/train-all.jsonl" --out "$OUT/vlm-text" \
    --steps 1500 --lr 1e-3 --minutes 40 --seed 0

# 6. Selection on the held-out set (geometric, run seed 0): best/ or final/ of each PPO run.
packlab bench --cases "$OUT/heldout.jsonl" --backend geometric --seeds 0 --workers 1 \
    --policies plan-fast,proposer,irbpp,tapnet,vlm --out "$OUT/heldout-eval" --no-figures \
    --policy-arg irbpp:model="$OUT/irbpp-ppo0/final" \
    --policy-arg tapnet:model="$OUT/tapnet-ppo0/final" \
    --policy-arg vlm:model="$OUT/vlm-text/final"

# 7. Every family the agents are measured on (issue 36, after the overflow rule): trained only on
#    layered layouts, both agents scored below the proposer on independently drawn boxes. Each
#    PPO run continues from the final/ model of steps 3-4 (the agents shipped before it) on
#    2,100 generated cases of five kinds, shuffled together so the trainer's own held-out cases
#    mix them too: layered (600, seed 4601), layered in layer order (300, 4602), cut in support
#    and base-height order (300 + 300, 4603-4604), random boxes (600, 4605). Selection by the
#    Overall on 90 other generated cases (layered, random, cut; seeds 4609-4611) among final/
#    after 45 min, final/ after 80 min and best/: irbpp's 80-min final/ (0.820; 0.804 at 45 min),
#    tapnet's 45-min final/ (0.797; 0.792 after 80 min), hence the two caps below.
mixed() {  # FILE SEED:PER_LEVEL:LAYOUT[:ORDER] ...: cases of several families, shuffled (seed 46)
  [ -f "$1" ] || python - "$@" <<'PY'
import random
import sys
from packlab.cases.write import save_cases
from packlab.datagen import generate_cases
from packlab.datagen.config import CaseConfig
path, specs = sys.argv[1], sys.argv[2:]
cases = []
for spec in specs:
    seed, n, layout, *order = spec.split(":")
    cfg = CaseConfig(layout=layout, **({"order": order[0]} if order else {}))
    cases += [c for lv in ("easy", "medium", "hard")
              for c in generate_cases(lv, int(n), int(seed), False, config=cfg, domain="train")]
random.Random(46).shuffle(cases)
save_cases(cases, path)
PY
}
mixed "$OUT/train-mix.jsonl" 4604:100:cut:base-height 4603:100:cut:support 4601:200:layered \
    4602:100:layered:layers 4605:200:random
mixed "$OUT/heldout-mix.jsonl" 4609:10:layered 4610:10:random 4611:10:cut:support
# Both runs side by side, one core each (80 min of wall time together).
packlab train rl --agent irbpp --init "$OUT/irbpp-ppo0/final" \
    --cases "$OUT/train-mix.jsonl" --lr 0.0001 --ent-coef 0.001 --minutes 80 --steps 2000000 \
    --envs 4 --vec dummy --eval-every 10000 --seed 0 --out "$OUT/irbpp-mix" &
irbpp_run=$!
packlab train rl --agent tapnet --placement proposer --init "$OUT/tapnet-ppo0/final" \
    --cases "$OUT/train-mix.jsonl" --lr 0.0001 --ent-coef 0.001 --minutes 45 --steps 2000000 \
    --envs 4 --vec dummy --eval-every 10000 --seed 0 --out "$OUT/tapnet-mix" &
tapnet_run=$!
wait "$irbpp_run"; wait "$tapnet_run"  # set -e: a failed run stops the script here
packlab bench --cases "$OUT/heldout-mix.jsonl" --backend geometric --seeds 0 --workers 1 \
    --policies irbpp,tapnet --out "$OUT/heldout-mix-eval" --no-figures \
    --policy-arg irbpp:model="$OUT/irbpp-mix/final" --policy-arg tapnet:model="$OUT/tapnet-mix/final"
