"""How well a behaviour-cloned agent predicts the teacher on states it was not fitted on.

Usage:
    python benchmarks/maintainers/rl_imitation_diag.py --states STATES.jsonl [--agent irbpp]
        [--epochs 30] [--width 64] [--work DIR]

Splits the labelled states by case (crc32 of the case id mod 5 == 0: held out, about 20 %),
fits on the rest (``packlab train rl-imitate``'s code path) and prints, per level, the share of
held-out states where the student's first-ranked row carries the teacher's most-preferred
target, beside "always row 0" (for irbpp: the proposer's first choice), and the held-out
cross-entropy.
"""

from __future__ import annotations

import argparse
import zlib
from pathlib import Path

import numpy as np
import torch

from packlab.cli.train_rl import demos_from_states
from packlab.rl.agent import load_agent
from packlab.rl.config import ImitationConfig
from packlab.rl.features import FeatureSpec
from packlab.rl.imitation import imitation_sample
from packlab.rl.imitation_fit import collate, imitate, row_logits
from packlab.vlm.candidate.states import read_states


def split(states_path: Path, spec: FeatureSpec):
    kept = [s for s in read_states(states_path) if s.label >= 0]
    train, test, levels = [], [], []
    for state, demo in zip(kept, demos_from_states(states_path), strict=True):
        sample = imitation_sample(demo, spec)
        if sample is None:
            continue
        if zlib.crc32(state.case_id.encode()) % 5 == 0:
            test.append(sample)
            levels.append(state.difficulty)
        else:
            train.append(sample)
    return train, test, np.array(levels)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--states", type=Path, required=True)
    p.add_argument("--agent", default="irbpp", choices=("irbpp", "tapnet"))
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--width", type=int, default=64)
    p.add_argument("--work", type=Path, default=Path("/tmp/rl_imitation_diag"))
    args = p.parse_args()
    torch.set_num_threads(1)
    spec = FeatureSpec.default(args.agent)
    train, test, levels = split(args.states, spec)
    out = args.work / args.agent
    cfg = ImitationConfig(agent=args.agent, out=str(out), epochs=args.epochs, width=args.width)
    r = imitate(train, cfg, str(args.states))
    print(
        f"fit on {len(train)} states: loss {r.losses[0]:.3f} -> {r.losses[-1]:.3f}, "
        f"first-ranked {r.accuracy:.3f}"
    )
    with torch.no_grad():
        batch = collate(test)
        logits = row_logits(load_agent(out).model.policy, batch)
        target, best = batch["target"], batch["target"].max(-1).values
        hit = target.gather(1, logits.argmax(-1, keepdim=True)).squeeze(1) >= best - 1e-6
        row0 = target[:, 0] >= best - 1e-6
        ce = float(-(target * torch.log_softmax(logits, -1)).sum(-1).mean())
    print(f"held-out states {len(test)}, cross-entropy {ce:.3f}")
    for level in ("easy", "medium", "hard", None):
        m = np.ones(len(levels), bool) if level is None else levels == level
        print(
            f"{level or 'all':>6}: n {m.sum():5d}  student {hit.numpy()[m].mean():.3f}  "
            f"row 0 {row0.numpy()[m].mean():.3f}"
        )


if __name__ == "__main__":
    main()
