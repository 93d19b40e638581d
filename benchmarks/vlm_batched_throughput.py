r"""Episodes per minute of the local ``vlm`` policy when the episodes of a bench worker decode
their answers together (the policy's ``batch`` option), against one episode per worker.

Usage:
    python benchmarks/vlm_batched_throughput.py                      # tiny qwen3_vl, 2 workers
    python benchmarks/vlm_batched_throughput.py --model tiny:qwen3_5:tiny --seeds 0-3 \
        --settings 1:off,4:off,4:auto,8:auto,8:auto:fresh
    python benchmarks/vlm_batched_throughput.py --attention 8 --per-level 2   # attention's share

Plays ``--per-level`` cases of each of the easy, medium and hard levels of packlab-bench-v1
(the first ones of each level), every ``--seeds`` seed, with ``packlab bench --policies vlm
--policy-arg vlm:model=MODEL --workers W --concurrency N`` on the mujoco backend, once per
setting. A setting is ``N:BATCH`` (concurrency and the policy's ``batch`` option), plus
``:fresh`` for ``reuse_cache=false`` (every step encodes its whole context: what batching
would cost without prefix caching). The first setting is the reference (today's way: one
episode per worker, ``1:off``).

For each setting it prints:

* episodes per minute over the invocation's wall time (invocations.jsonl), and the speedup
  over the reference;
* CPU seconds of the bench and its workers, and episodes per CPU minute with its speedup: on a
  machine shared with other work the wall time moves with the other load; CPU time much less;
* the mean batch size: answers per decode, counting those decoded alone as batches of one
  (``packlab.vlm.infer.batching.record_batches`` logs each batch the workers run);
* whether every episode's actions and metrics equal the reference's (greedy decoding gives the
  same answers batched or alone, up to floating-point ties).

``--attention N`` plays the same episodes in one process, alone and N at once, and prints the
CPU seconds the model's attention took against the whole: attention reads each episode's own
keys and values, which no batch shares, so it bounds what batching can gain.

A random-weight tiny model answers text that never parses, so every step is an invalid step:
no placement is simulated and the model is nearly all the work (the per-step profile of
``--profile`` shows it).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from packlab.bench.options import parse_seeds
from packlab.bench.suites import load_suite
from packlab.cases.write import save_cases

#: Runs the CLI after having every batcher of its workers log its batches to argv[1].
CLI = (
    "import sys; from packlab.vlm.infer import batching; batching.record_batches(sys.argv[1]); "
    "from packlab.cli.main import main; sys.exit(main(sys.argv[2:]))"
)
LEVELS = ("easy", "medium", "hard")
#: Record fields that are timings: they differ from run to run.
TIMING_KEYS = {"wall_time_s", "decision_s", "decision_cpu_s"}


@dataclass(frozen=True)
class Setting:
    concurrency: int
    batch: str
    fresh: bool  # reuse_cache=false

    @classmethod
    def parse(cls, text: str) -> Setting:
        parts = text.split(":")
        if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] != "fresh"):
            raise SystemExit(f"setting {text!r}: expected N:BATCH or N:BATCH:fresh")
        return cls(int(parts[0]), parts[1], len(parts) == 3)

    @property
    def label(self) -> str:
        return f"{self.concurrency}:{self.batch}" + (":fresh" if self.fresh else "")


@dataclass(frozen=True)
class Row:
    setting: Setting
    episodes: int
    answers: int
    wall_s: float
    cpu_s: float
    batches: int  # batched decodes
    batched_answers: int  # answers in them
    records: dict[tuple[str, int], Any]

    @property
    def per_minute(self) -> float:
        return 60.0 * self.episodes / self.wall_s

    @property
    def per_cpu_minute(self) -> float:
        return 60.0 * self.episodes / self.cpu_s

    @property
    def mean_batch(self) -> float:
        alone = self.answers - self.batched_answers
        return self.answers / max(1, self.batches + alone)


def pick_cases(per_level: int, out: Path) -> Path:
    """The first ``per_level`` cases of each level of packlab-bench-v1, as a case file."""
    cases = load_suite("packlab-bench-v1")
    chosen = [c for level in LEVELS for c in _level(cases, level)[:per_level]]
    return save_cases(chosen, out)


def _level(cases: list[Any], level: str) -> list[Any]:
    return [c for c in cases if c.difficulty == level]


def comparable(record: dict[str, Any]) -> Any:
    """What must not change between settings: each step's action and validity, the metrics."""
    steps = [(s["action"], s["valid"], s["reason"]) for s in record["steps"]]
    metrics = {k: v for k, v in record["metrics"].items() if k not in TIMING_KEYS}
    return steps, metrics


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_one(args: argparse.Namespace, setting: Setting, cases: Path, scratch: Path) -> Row:
    out = scratch / setting.label.replace(":", "-")
    log = scratch / f"{out.name}-batches.jsonl"
    argv = ["bench", "--cases", str(cases), "--policies", "vlm", "--backend", "mujoco"]
    argv += ["--seeds", args.seeds, "--workers", str(args.workers)]
    argv += ["--concurrency", str(setting.concurrency), "--out", str(out)]
    argv += ["--policy-arg", f"vlm:model={args.model}", "--policy-arg", "vlm:device=cpu"]
    argv += ["--policy-arg", f"vlm:batch={setting.batch}"]
    argv += ["--policy-arg", f"vlm:max_batch={args.max_batch}"]
    if setting.fresh:
        argv += ["--policy-arg", "vlm:reuse_cache=false"]
    for option in args.option:
        argv += ["--policy-arg", f"vlm:{option}"]
    argv += ["--no-progress", "--no-figures", "--no-html"]
    cpu0 = children_cpu_s()
    done = subprocess.run(
        [sys.executable, "-c", CLI, str(log), *argv],
        check=False,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        capture_output=True,
        text=True,
    )
    cpu_s = children_cpu_s() - cpu0
    if done.returncode != 0:
        raise SystemExit(f"packlab bench failed (exit {done.returncode}):\n{done.stderr[-3000:]}")
    invocation = json.loads((out / "invocations.jsonl").read_text().splitlines()[-1])
    records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    failed = [r for r in records if r.get("status") != "ok"]
    if failed:
        raise SystemExit(f"{len(failed)} episodes failed, e.g. {json.dumps(failed[0])[:2000]}")
    batches = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    return Row(
        setting,
        invocation["ran"],
        sum(len(r["steps"]) for r in records),
        invocation["wall_s"],
        cpu_s,
        len(batches),
        sum(b["rows"] for b in batches),
        {(r["case_id"], r["seed"]): comparable(r) for r in records},
    )


def table(rows: list[Row]) -> str:
    """The results as a Markdown table, speedups over the first row."""
    ref = rows[0]
    head = (
        "| setting | episodes | wall s | episodes/min | speedup | CPU s | episodes/CPU-min "
        "| speedup | mean batch | same records |"
    )
    rule = "| :-- | --: | --: | --: | --: | --: | --: | --: | --: | :-- |"
    lines = [head, rule]
    for r in rows:
        same = "yes" if r.records == ref.records else _differences(ref, r)
        lines.append(
            f"| {r.setting.label} | {r.episodes} | {r.wall_s:.1f} | {r.per_minute:.1f} "
            f"| {r.per_minute / ref.per_minute:.2f}x | {r.cpu_s:.1f} | {r.per_cpu_minute:.1f} "
            f"| {r.per_cpu_minute / ref.per_cpu_minute:.2f}x | {r.mean_batch:.2f} | {same} |"
        )
    return "\n".join(lines)


def _differences(ref: Row, row: Row) -> str:
    differ = sorted(k for k in ref.records if ref.records[k] != row.records.get(k))
    return f"no: {len(differ)} episodes differ ({', '.join(f'{c}/{s}' for c, s in differ[:3])})"


def _value(text: str) -> Any:
    """A --option value as the bench reads one: JSON (numbers, true/false), else the text."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def profile(model: str, extra: list[str]) -> None:
    """Where one episode's time goes, single thread: model (encode, prefill, decode), prompt
    rendering, and the rest (physics, observation)."""
    import torch

    from packlab.policies import make_policy
    from packlab.sim.episode import run_episode

    torch.set_num_threads(1)
    cases = load_suite("packlab-bench-v1")
    options = {k: _value(v) for k, v in (o.split("=", 1) for o in extra)}
    policy = make_policy("vlm", model=model, device="cpu", batch="off", **options)
    policy.load()
    print("| level | steps | episode s | render s | encode s | prefill s | decode s | rest s |")
    print("| :---- | ----: | --------: | -------: | -------: | --------: | -------: | -----: |")
    for level in LEVELS:
        case = next(c for c in cases if c.difficulty == level)
        t0 = time.perf_counter()
        run_episode(case, policy, seed=0, backend="mujoco")
        total = time.perf_counter() - t0
        parts = {k: sum(s[k] for s in policy.step_log) for k in ("render_s", "encode_s")}
        parts |= {k: sum(s[k] for s in policy.step_log) for k in ("prefill_s", "decode_s")}
        rest = total - sum(parts.values())
        print(
            f"| {level} | {len(policy.step_log)} | {total:.2f} | {parts['render_s']:.2f} "
            f"| {parts['encode_s']:.2f} | {parts['prefill_s']:.2f} | {parts['decode_s']:.2f} "
            f"| {rest:.2f} |"
        )
    print("(wall seconds, one episode per level; rest: physics, observations, parsing)")


def attention_share(model: str, per_level: int, seeds: tuple[int, ...], concurrency: int) -> None:
    """Where the model's time goes with the episodes of one process answered alone and batched:
    the seconds spent in scaled dot-product attention (every call of the model's attention,
    prefill and decode) against the seconds spent in the model's forwards (one thread, torch
    on one core). Attention reads each episode's own context, whose keys and values no batch
    shares, so batching cannot shrink it."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    import torch

    from packlab.policies import make_policy
    from packlab.sim.episode import run_episode

    torch.set_num_threads(1)
    cases = load_suite("packlab-bench-v1")
    jobs = [(c, s) for level in LEVELS for c in _level(cases, level)[:per_level] for s in seeds]
    sdpa = torch.nn.functional.scaled_dot_product_attention
    lock, spent = threading.Lock(), [0.0]

    def timed(*a: Any, **k: Any) -> Any:
        t0 = time.thread_time()
        out = sdpa(*a, **k)
        with lock:
            spent[0] += time.thread_time() - t0
        return out

    print("| episodes at once | episodes | CPU s | attention CPU s | share |")
    print("| --: | --: | --: | --: | --: |")
    torch.nn.functional.scaled_dot_product_attention = timed
    try:
        for n in (1, concurrency):
            batch = "on" if n > 1 else "off"

            def play(job: tuple[Any, int], batch: str = batch) -> None:
                policy = make_policy("vlm", model=model, device="cpu", batch=batch, threads=1)
                run_episode(job[0], policy, seed=job[1], backend="mujoco")

            play(jobs[0])  # load the model and warm up
            spent[0] = 0.0
            cpu0 = time.process_time()
            with ThreadPoolExecutor(n) as pool:
                list(pool.map(play, jobs))
            cpu = time.process_time() - cpu0
            print(f"| {n} | {len(jobs)} | {cpu:.1f} | {spent[0]:.1f} | {spent[0] / cpu:.0%} |")
    finally:
        torch.nn.functional.scaled_dot_product_attention = sdpa


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--model", default="tiny:qwen3_vl:tiny", help="the vlm policy's model")
    p.add_argument("--settings", default="1:off,4:auto,8:auto", help="N:BATCH[:fresh] list")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--per-level", type=int, default=2, help="cases of each level")
    p.add_argument("--seeds", default="0-3", help="run seeds (episodes = 3 x per-level x seeds)")
    p.add_argument("--max-batch", type=int, default=8, help="the policy's max_batch")
    p.add_argument(
        "--option", action="append", default=[], help="another vlm option, KEY=VALUE (repeatable)"
    )
    p.add_argument("--profile", action="store_true", help="first, one episode per level alone")
    p.add_argument(
        "--attention",
        type=int,
        metavar="N",
        help="only the attention share of the model's time, alone and N episodes at once "
        "(one process)",
    )
    args = p.parse_args()
    if args.attention:
        attention_share(args.model, args.per_level, parse_seeds(args.seeds), args.attention)
        return
    settings = [Setting.parse(s) for s in args.settings.split(",")]
    print(
        f"packlab-bench-v1, {args.per_level} cases per level, seeds {args.seeds}, mujoco, "
        f"model {args.model} {' '.join(args.option)}, workers {args.workers}, "
        f"{os.cpu_count()} CPUs, "
        f"load average {os.getloadavg()[0]:.1f}",
        flush=True,
    )
    if args.profile:
        profile(args.model, args.option)
    rows: list[Row] = []
    with tempfile.TemporaryDirectory(prefix="packlab-vlm-batch-") as scratch:
        cases = pick_cases(args.per_level, Path(scratch) / "cases.jsonl")
        for setting in settings:
            rows.append(run_one(args, setting, cases, Path(scratch)))
            r = rows[-1]
            print(
                f"{setting.label}: {r.episodes} episodes in {r.wall_s:.1f} s "
                f"(load average {os.getloadavg()[0]:.1f})",
                flush=True,
            )
    print(table(rows))
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
