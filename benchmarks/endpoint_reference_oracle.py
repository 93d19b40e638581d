r"""The oracle's answers served through ``endpoint prompt=reference`` on every bundled suite.

Usage:
    python benchmarks/endpoint_reference_oracle.py                 # three suites, seeds 0-2
    python benchmarks/endpoint_reference_oracle.py --suites packlab-bench-v1 --prompt packlab

A scripted OpenAI-compatible server runs in this process
(:mod:`packlab.vlm.serve.oracle_answers`): it answers every request the ``endpoint`` policy sends
with the oracle's action for that step, written in the protocol's answer format. The bench plays
each suite through it (``packlab bench --policies endpoint --policy-arg endpoint:prompt=...``) on
the MuJoCo backend with several episodes in flight, and the table shows what came back: Average
Overall with its 95 % bootstrap interval (the oracle itself scores 1.000 on every bundled suite,
so anything lower was lost in the request, the answer or its reading), the requests the server
answered, and those it had no recorded answer for (a prompt the recording did not foresee).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from packlab.bench.suites import load_suite
from packlab.vlm.serve.oracle_answers import oracle_model
from packlab.vlm.serve.server import serve

CLI = "import sys; from packlab.cli.main import main; sys.exit(main(sys.argv[1:]))"
SUITES = "packlab-bench-v1,packlab-bench-layers-v1,packlab-bench-cut-v1"


def run_suite(args: argparse.Namespace, suite: str, scratch: Path) -> str:
    """One suite through the scripted server; its table row."""
    seeds = [int(s) for s in args.seeds.split(",")]
    policy_args = {"prompt": args.prompt}
    t0 = time.perf_counter()
    model = oracle_model(load_suite(suite), seeds, policy_args)
    record_s = time.perf_counter() - t0
    out = scratch / suite
    with serve(model) as server:
        argv = ["bench", "--cases", suite, "--policies", "endpoint", "--backend", args.backend]
        argv += ["--seeds", args.seeds, "--workers", str(args.workers)]
        argv += ["--concurrency", str(args.concurrency), "--out", str(out)]
        argv += ["--policy-arg", f"endpoint:base_url={server.base_url}"]
        argv += ["--policy-arg", f"endpoint:prompt={args.prompt}"]
        argv += ["--policy-arg", "endpoint:tag_requests=true"]  # the oracle's key needs it
        argv += ["--no-progress", "--no-figures", "--no-html"]
        done = subprocess.run(
            [sys.executable, "-c", CLI, *argv], check=False, capture_output=True, text=True
        )
    if not (out / "summary.json").exists():
        raise SystemExit(f"packlab bench failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
    for line in (out / "episodes.jsonl").read_text().splitlines():
        record = json.loads(line)
        if "error_kind" in record:  # shown, and counted in the row
            print(f"  {record['case_id']} seed {record['seed']}: {record['error'][:300]}")
    summary = json.loads((out / "summary.json").read_text())
    mean = summary["table"]["endpoint"]["average"]["overall"]["mean"] or float("nan")
    interval = summary["intervals"]["policies"]["endpoint"]["cells"]["average"]["overall"]
    low, high = interval or (float("nan"), float("nan"))  # None: too few finished episodes
    episodes = summary["counts"]["endpoint"]["episodes"]
    errors = summary["counts"]["endpoint"]["errors"]
    return (
        f"| {suite} | {episodes} | {errors} | {mean:.3f} [{low:.3f}, {high:.3f}] "
        f"| {model.requests} | {model.unknown} | {record_s:.1f} |"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--suites", default=SUITES, help="comma-separated bundled suites")
    p.add_argument("--prompt", choices=("reference", "packlab"), default="reference")
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--backend", choices=("geometric", "mujoco"), default="mujoco")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--concurrency", type=int, default=8)
    args = p.parse_args()
    print(
        f"endpoint prompt={args.prompt}, oracle answers, backend {args.backend}, seeds "
        f"{args.seeds}, workers {args.workers} x concurrency {args.concurrency}, "
        f"load average {os.getloadavg()[0]:.1f}",
        flush=True,
    )
    header = (
        "| suite | episodes | errors | Average Overall [95 % CI] | requests | unanswered "
        "| recording s |"
    )
    rows = [
        header,
        "| --- | -: | -: | -: | -: | -: | -: |",
    ]
    with tempfile.TemporaryDirectory(prefix="packlab-oracle-endpoint-") as scratch:
        for suite in args.suites.split(","):
            rows.append(run_suite(args, suite, Path(scratch)))
            print(rows[-1], flush=True)
    print("\n".join(rows))


if __name__ == "__main__":
    main()
