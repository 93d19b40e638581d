"""SFT training throughput on CPU: labelled actions per second, ``packlab train sft`` against the
trainer of a baseline revision (one example per step, its whole history, the loss on its last
answer; a hand-written accelerate loop).

Both run as ``python -m packlab.cli.main train sft`` subprocesses on the same dataset, one after
the other, with the same model and batch settings (micro-batch 1, grad-accum 8: 8 examples per
optimizer step); the baseline's code from a temporary ``git worktree`` (PYTHONPATH=<it>/src) on
its own per-step JSONL export of that dataset. Only the training phase is timed: steps 2..N,
from the time each step's line appears in the run's ``loss_log.jsonl`` (this script polls it;
the baseline's own ``elapsed_s`` is printed beside it as a check). Step 1 is left out, as is
setup (model build, data loading, length check) and the final save.

Labelled actions: the baseline's examples carry one each; the new trainer's conversations carry
one per assistant turn, counted as the mean turns per training conversation (sft_config.json:
train_labelled_actions / train_examples) times the conversations of steps 2..N (the trainer's
shuffled order is its own). Tokens: the new run logs its cumulative ``num_tokens``; the
baseline logs none, so its tokens/s is estimated with the mean tokens of its examples (every
step's context through its answer, counted with the project tokenizer) and marked ``~``.

    python benchmarks/sft_throughput.py                       # 100 episodes, 10 steps
    python benchmarks/sft_throughput.py --data /tmp/sft-size/data --steps 10
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from sft_export_size import (
    baseline_env,
    baseline_worktree,
    make_dataset,
    markdown,
    old_export,
    scaled_episodes,
    work_dir,
)

from packlab.vlm.data import sft_tokens

REPO = Path(__file__).resolve().parents[1]
#: Log lines are polled this often; a CPU step of the tiny model takes seconds.
POLL_S = 0.05
#: The baseline cut the oldest history steps to fit 4096 tokens by default; this keeps every
#: step's whole history, as the new trainer does, so both learn from the same contexts.
OLD_MAX_LENGTH = 65536


@dataclass(frozen=True)
class Run:
    """One training subprocess as timed from outside and as its files describe it."""

    out: Path
    step_times: dict[int, float]  # optimizer step -> when its log line appeared (perf_counter)
    log: list[dict]
    config: dict
    wall_s: float

    def seconds(self, first: int, last: int) -> float:
        return self.step_times[last] - self.step_times[first]


def _new_lines(path: Path, seen: int) -> list[dict]:
    if not path.is_file():
        return []
    lines = path.read_text().splitlines()
    out = []
    for line in lines[seen:]:
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            break  # a line being written: read it next time
    return out


def train(argv: list[str], env: dict[str, str], out: Path, console: Path) -> Run:
    """Run ``packlab train sft ARGV --out OUT`` and time each step's log line."""
    cmd = [sys.executable, "-m", "packlab.cli.main", "train", "sft", *argv, "--out", str(out)]
    log_path = out / "loss_log.jsonl"
    step_times: dict[int, float] = {}
    lines: list[dict] = []
    t0 = time.perf_counter()
    with console.open("w") as fh:
        proc = subprocess.Popen(cmd, env=env, stdout=fh, stderr=subprocess.STDOUT, cwd=REPO)
        while True:
            done = proc.poll() is not None
            for line in _new_lines(log_path, len(lines)):
                lines.append(line)
                if "loss" in line and "step" in line:
                    step_times.setdefault(int(line["step"]), time.perf_counter())
            if done:
                break
            time.sleep(POLL_S)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)}: exit {proc.returncode}; see {console}")
    config = json.loads((out / "sft_config.json").read_text())
    return Run(out, step_times, lines, config, time.perf_counter() - t0)


def common_args(args: argparse.Namespace) -> list[str]:
    return [
        "--model",
        args.model,
        "--micro-batch",
        "1",
        "--grad-accum",
        "8",
        "--max-steps",
        str(args.steps),
        "--seed",
        str(args.seed),
    ]


def new_args(args: argparse.Namespace, data: Path) -> list[str]:
    # No validation, no checkpoint, no TensorBoard: nothing but training in the timed steps.
    extra = ["--report-to", "none", "--val-fraction", "0", "--save-every", "100000"]
    return ["--data", str(data), *common_args(args), *extra]


def old_args(args: argparse.Namespace, data: Path) -> list[str]:
    return ["--data", str(data), *common_args(args), "--max-length", str(args.old_max_length)]


def old_mean_tokens(data: Path) -> float:
    """Mean tokens of the baseline's examples: every step's conversation prefix through its
    answer (what its per-step example held), over the whole dataset."""
    counter = sft_tokens.project_counter()
    files = sft_tokens.export_files(data)
    episodes = {r["episode_id"] for r in sft_tokens.read_index(files)}
    convs = sft_tokens.whole_episodes(sft_tokens.read_conversations(files, episodes))
    ends = [n for c in convs for n in counter.turn_end_tokens(c)]
    return sum(ends) / len(ends)


def figures(run: Run, new: bool, old_tokens: float, steps: int) -> dict:
    """Examples, labelled actions and tokens per second over steps 2..N."""
    batch = int(run.config["global_batch"])
    examples = (steps - 1) * batch
    seconds = run.seconds(1, steps)
    if new:
        turns = run.config["train_labelled_actions"] / run.config["train_examples"]
        tokens = {int(x["step"]): x["num_tokens"] for x in run.log if "num_tokens" in x}
        rate = f"{(tokens[steps] - tokens[1]) / seconds:,.0f}"
    else:
        turns = 1.0
        rate = f"~{examples * old_tokens / seconds:,.0f}"
    return {
        "examples": examples,
        "actions": examples * turns,
        "seconds": seconds,
        "examples_s": examples / seconds,
        "actions_s": examples * turns / seconds,
        "tokens_s": rate,
    }


def own_clock(run: Run, new: bool, steps: int) -> str:
    """The run's own time figure, as a check on the polled one."""
    if new:
        runtime = next((x["train_runtime"] for x in run.log if "train_runtime" in x), None)
        return f"new train_runtime (its whole train(), steps 1..{steps}) = {runtime} s"
    elapsed = {int(x["step"]): x["elapsed_s"] for x in run.log if "elapsed_s" in x}
    return f"old elapsed_s, steps 2..{steps} = {elapsed[steps] - elapsed[1]:.2f} s"


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return f"{cpu}; {os.cpu_count()} cores ({affinity} usable by this process)"


def load() -> str:
    return "/".join(f"{x:.2f}" for x in os.getloadavg())


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", metavar="DIR", help="dataset with its sft/*.parquet; default: made")
    ap.add_argument(
        "--episodes", type=int, default=100, help="made dataset: 9000:7000:4000 split; 100"
    )
    ap.add_argument("--data-seed", type=int, default=20250, help="made dataset's user seed")
    ap.add_argument("--model", default="tiny:qwen3_vl:tiny")
    ap.add_argument("--steps", type=int, default=10, help="optimizer steps per run (>= 2)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--baseline", default="c941aee", help="revision of the old trainer")
    ap.add_argument("--old-max-length", type=int, default=OLD_MAX_LENGTH)
    ap.add_argument("--keep", metavar="DIR", help="write data and runs here and keep them")
    args = ap.parse_args()
    if args.steps < 2:
        ap.error("--steps must be >= 2 (step 1 is left out of the timing)")
    return args


def print_table(results: dict[str, dict]) -> None:
    old = results.get("old")
    header = ["trainer", "examples/s", "labelled actions/s", "tokens/s", "ratio (actions/s)"]
    rows = []
    for name, r in results.items():
        ratio = f"{r['actions_s'] / old['actions_s']:.2f}" if old else "-"
        rows.append(
            [
                f"{name} ({r['examples']} ex., {r['actions']:.0f} actions, {r['seconds']:.1f} s)",
                f"{r['examples_s']:.3f}",
                f"{r['actions_s']:.3f}",
                r["tokens_s"],
                ratio,
            ]
        )
    print(markdown(header, rows))


def check_enough(data: Path, steps: int) -> None:
    """Every timed step must hold 8 conversations: past the end of an epoch the trainer steps on
    the few left over, and a step of 2 would count as 8 here."""
    files = sft_tokens.export_files(data)
    if not files:
        raise SystemExit(f"{data}: no sft/*.parquet (write it: packlab export sft {data})")
    n = len(sft_tokens.read_index(files))
    if n < steps * 8:
        raise SystemExit(f"{data}: {n} conversations, fewer than {steps} steps x 8; more episodes")


def benchmark(args: argparse.Namespace, work: Path, worktree: Path | None) -> None:
    data = Path(args.data) if args.data else None
    if data is None:
        data = make_dataset(work / "data", scaled_episodes(args.episodes), args.data_seed, 224)
    check_enough(data, args.steps)
    print(f"machine: {machine()}; python {platform.python_version()}")
    print(f"data: {data}; model {args.model}; {args.steps} steps of 8 (micro-batch 1 x 8)")
    results, checks = {}, []
    if worktree is not None:
        old_data = old_export(worktree, data, work / "old-data")
        print(f"load average before old: {load()}")
        run = train(
            old_args(args, old_data), baseline_env(worktree), work / "old", work / "old.log"
        )
        results["old"] = figures(run, False, old_mean_tokens(data), args.steps)
        checks.append(own_clock(run, False, args.steps))
    print(f"load average before new: {load()}")
    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    run = train(new_args(args, data), env, work / "new", work / "new.log")
    results["new"] = figures(run, True, 0.0, args.steps)
    checks.append(own_clock(run, True, args.steps))
    print(f"load average after: {load()}")
    print()
    print_table(results)
    print("\n".join(checks))


def main() -> None:
    args = parse_args()
    with contextlib.ExitStack() as stack:
        work = work_dir(stack, args.keep, "sft-speed-")
        worktree = stack.enter_context(baseline_worktree(args.baseline))
        benchmark(args, work, worktree)


if __name__ == "__main__":
    main()
