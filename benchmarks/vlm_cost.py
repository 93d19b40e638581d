"""What one candidate-mode step costs: tokens, bytes on disk, milliseconds per decision.

Usage:
    python benchmarks/vlm_cost.py --states RUN/r0/states.jsonl --model RUN/final [--n 300]

Prints, per level, over the first ``--n`` states of each level in the file: prompt tokens per
step with the short and the full instructions (the project tokenizer), bytes per stored state,
and the mean milliseconds of the proposer and of the pointer model's forward pass (one thread,
batch 1) per decision. Timings depend on the machine's load; the table says nothing about it.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

from packlab.policies.candidates import propose
from packlab.vlm.candidate.pointer import encode
from packlab.vlm.candidate.saved import load_pointer
from packlab.vlm.candidate.scoring import PromptSettings, score_listed
from packlab.vlm.candidate.states import listed_of, observation_of, read_states


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--states", required=True)
    ap.add_argument("--model", required=True)
    ap.add_argument("--n", type=int, default=300)
    args = ap.parse_args()
    torch.set_num_threads(1)
    model = load_pointer(args.model)
    tok = model.vlm.tokenizer
    lines = Path(args.states).read_bytes().split(b"\n")
    by: dict[str, list] = defaultdict(list)
    for s, raw in zip(read_states(Path(args.states)), lines, strict=False):
        if len(by[s.difficulty]) < args.n:
            by[s.difficulty].append((s, len(raw) + 1))
    print("| level | states | tokens/step (short) | tokens/step (full) | bytes/state "
          "| proposer ms | model ms |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|")
    for level in ("easy", "medium", "hard"):
        rows = by.get(level, [])
        if not rows:
            continue
        short = [len(encode(tok, s, "short").ids) for s, _ in rows]
        full = [len(encode(tok, s, "full").ids) for s, _ in rows]
        prop, fwd = [], []
        for s, _ in rows[:100]:
            obs = observation_of(s)
            t0 = time.perf_counter()
            propose(obs)
            t1 = time.perf_counter()
            score_listed(model, obs, listed_of(s), PromptSettings())
            t2 = time.perf_counter()
            prop.append(t1 - t0)
            fwd.append(t2 - t1)
        print(f"| {level} | {len(rows)} | {np.mean(short):.0f} | {np.mean(full):.0f} "
              f"| {np.mean([b for _, b in rows]):.0f} | {1e3 * np.mean(prop):.1f} "
              f"| {1e3 * np.mean(fwd):.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
