"""A small MLP student over listed placements' line vectors: what the inputs can teach, fast.

Usage:
    python benchmarks/maintainers/student_probe.py train OUT.pt STATES.jsonl [STATES.jsonl ...]
        [--no-level-fit]
    python benchmarks/maintainers/student_probe.py loop MODEL.pt --k 16 --per-level 10 --seed 7412
    python benchmarks/maintainers/student_probe.py dagger MODEL.pt OUT.jsonl --k 16 --per-level 150
        --seed 4403

The model scores each listed line from its vector (:mod:`packlab.policies.line_vector`), the mean
vector of the list and three globals (objects left, peak height, buffer size) with one shared
MLP, softmax over the lines, trained on the planner's soft targets. It is the cheap stand-in used
to choose the line vector's columns and the students' K (docs/vlm.md, "Learning the planner"):
with the geometry alone it plays like index 0, with the level fit it plays above it. ``dagger``
plays new generated cases with a trained probe and records the planner's labels of the states
the probe reaches (a DAgger round; the VLM's round 1 trains on them). Cases are generated in
the train seed domain; held-out by case id (every fifth case) for the match figures. One thread.
"""

from __future__ import annotations

import argparse
import sys
import zlib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

from packlab.core.types import Observation
from packlab.datagen import generate_cases
from packlab.policies.candidates import ProposerConfig, propose
from packlab.policies.level_fit import N_FEATURES
from packlab.policies.line_vector import LINE_VECTOR_SIZE, line_vectors
from packlab.policies.listed import ListedTeacher
from packlab.policies.registry import make_policy
from packlab.sim.episode import run_episode
from packlab.vlm.candidate.collect import Labeller
from packlab.vlm.candidate.states import append_states, listed_of, observation_of
from packlab.vlm.candidate.states_guard import checked_states

N_GLOBALS = 3
LEVELS = ("easy", "medium", "hard")


def make_net(level_fit: bool = True) -> torch.nn.Module:
    f = (LINE_VECTOR_SIZE if level_fit else LINE_VECTOR_SIZE - N_FEATURES) + N_GLOBALS
    return torch.nn.Sequential(
        torch.nn.Linear(2 * f, 128), torch.nn.ReLU(), torch.nn.Linear(128, 128), torch.nn.ReLU(),
        torch.nn.Linear(128, 1),
    )  # fmt: skip


def rows(obs: Observation, listed, level_fit: bool = True) -> np.ndarray:
    g = [obs.remaining / 32, obs.heightmap.max() / obs.container.height_mm, len(obs.shown) / 10]
    v = line_vectors(obs, listed)
    v = v if level_fit else v[:, : LINE_VECTOR_SIZE - N_FEATURES]
    return np.concatenate([v, np.repeat(np.asarray([g], np.float32), len(listed), 0)], 1)


def scores(net: torch.nn.Module, x: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    ctx = (x * m[..., None]).sum(1, keepdim=True) / m.sum(1, keepdim=True)[..., None]
    return net(torch.cat([x, ctx.expand_as(x)], -1)).squeeze(-1).masked_fill(~m, -1e9)


def _arrays(files, level_fit: bool, hard: bool):
    xs, ts, labels, held = [], [], [], []
    for f in files:
        for s in checked_states(Path(f)):  # training data: rows of suite cases are refused
            if s.label < 0:
                continue
            t = np.zeros(len(s.listed), np.float32)
            if s.soft and not hard:
                t[:] = s.soft
            else:
                t[s.label] = 1
            xs.append(rows(observation_of(s), listed_of(s), level_fit))
            ts.append(t)
            labels.append(s.label)
            held.append(zlib.crc32(s.case_id.encode()) % 5 == 0)
    k, f = max(len(x) for x in xs), xs[0].shape[1]
    x = np.zeros((len(xs), k, f), np.float32)
    t = np.zeros((len(xs), k), np.float32)
    m = np.zeros((len(xs), k), bool)
    for i, (a, b) in enumerate(zip(xs, ts)):
        x[i, : len(a)], t[i, : len(b)], m[i, : len(a)] = a, b, True
    return torch.tensor(x), torch.tensor(t), torch.tensor(m), np.array(labels), np.array(held)


def train(files, out: str, level_fit: bool, hard: bool = False, epochs: int = 60) -> None:
    """Fit on the states' soft targets (``hard``: on the teacher's pick alone)."""
    x, t, m, labels, held = _arrays(files, level_fit, hard)
    torch.manual_seed(0)
    net = make_net(level_fit)
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    tr, te = np.flatnonzero(~held), np.flatnonzero(held)
    for ep in range(epochs):
        perm = np.random.default_rng(ep).permutation(tr)
        for b in range(0, len(perm), 64):
            i = perm[b : b + 64]
            loss = -(t[i] * torch.log_softmax(scores(net, x[i], m[i]), -1)).sum(-1).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    with torch.no_grad():
        pick = scores(net, x[te], m[te]).argmax(-1)
    match = float((pick.numpy() == labels[te]).mean())
    in_soft = float((t[te][torch.arange(len(te)), pick] > 0).float().mean())
    print(f"train {len(tr)} held-out {len(te)}: match {match:.3f}, pick in the teacher's target "
          f"{in_soft:.3f}, index 0 {float((labels[te] == 0).mean()):.3f}")  # fmt: skip
    torch.save({"net": net.state_dict(), "level_fit": level_fit}, out)


class ProbeStudent:
    name = "probe"

    def __init__(self, path: str, k: int) -> None:
        saved = torch.load(path)
        self.level_fit = saved["level_fit"]
        self.net = make_net(self.level_fit)
        self.net.load_state_dict(saved["net"])
        self.config = ProposerConfig(k=k)

    def reset(self, case, seed: int) -> None:
        self.fallback = make_policy("sdf")
        self.fallback.reset(case, seed)

    def act(self, obs: Observation):
        listed = propose(obs, self.config)
        if not listed:
            return self.fallback.act(obs)
        x = torch.tensor(rows(obs, listed, self.level_fit))[None]
        with torch.no_grad():
            s = scores(self.net, x, torch.ones(1, len(listed), dtype=torch.bool))[0]
        return listed[int(s.argmax())].action


def loop(path: str, k: int, per_level: int, seed: int) -> None:
    res = {}
    for level in LEVELS:
        cases = generate_cases(level, per_level, seed, False, domain="train")
        res[level] = float(np.mean([
            run_episode(c, ProbeStudent(path, k), seed=0, backend="geometric").metrics.overall
            for c in cases
        ]))  # fmt: skip
    avg = np.mean(list(res.values()))
    levels = ", ".join(f"{a} {b:.3f}" for a, b in res.items())
    print(f"{path} K={k}: {levels}, avg {avg:.3f}")


def _dagger_case(job):
    torch.set_num_threads(1)
    case, path, k = job
    labeller = Labeller(ListedTeacher("plan"), ProposerConfig(k=k), "student-r1",
                        ProbeStudent(path, k))  # fmt: skip
    result = run_episode(case, labeller, seed=0, backend="geometric")
    return labeller.states, result.metrics.overall


def dagger(path: str, out: str, k: int, per_level: int, seed: int, workers: int) -> None:
    cases = [c for lv in LEVELS for c in generate_cases(lv, per_level, seed, False, domain="train")]
    overall = []
    with ProcessPoolExecutor(workers) as pool:
        for states, o in pool.map(_dagger_case, [(c, path, k) for c in cases], chunksize=1):
            append_states(Path(out), states)
            overall.append(o)
    print(f"student Overall on the {len(cases)} round cases: {np.mean(overall):.3f}")


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("command", choices=("train", "loop", "dagger"))
    p.add_argument("paths", nargs="+")
    p.add_argument("--k", type=int, default=16)
    p.add_argument("--per-level", type=int, default=10)
    p.add_argument("--seed", type=int, default=7412)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--no-level-fit", action="store_true")
    p.add_argument("--hard", action="store_true", help="train on the pick alone, not soft targets")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    if a.command == "train":
        train(a.paths[1:], a.paths[0], not a.no_level_fit, a.hard)
    elif a.command == "loop":
        loop(a.paths[0], a.k, a.per_level, a.seed)
    else:
        dagger(a.paths[0], a.paths[1], a.k, a.per_level, a.seed, a.workers)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
