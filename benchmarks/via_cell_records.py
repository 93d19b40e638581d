"""Whether the bench played through a cell service writes the in-process honest run's records.

    python benchmarks/via_cell_records.py --in-process RUN [--policy plan-fast]
                                          [--noise structured-light] [--out DIR]

Starts ``packlab cell serve --policy POLICY`` on a free local port, plays ``packlab bench
--via-cell`` with the run's suite, seeds and robot-path options into ``--out`` (resumes there),
stops the service and compares the two runs' records of POLICY episode by episode, with the
keys that time the run left out (wall and CPU seconds: the only keys the two paths may differ
in). ``--in-process`` is an existing honest run directory of the same code, e.g. the results
page's robot-path run; its ``config.json`` gives the cases, seeds and sensing. Prints the count
of identical records, the differing ones with the first step where each differs, and the mean
Overall of each path, with the load average and both runs' wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

#: Record keys that time the run: the only keys the two paths may differ in.
TIMES = {"timing", "decision_s", "decision_cpu_s", "wall_time_s", "policy_time_s"}


def untimed(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: untimed(v) for k, v in value.items() if k not in TIMES}
    if isinstance(value, list):
        return [untimed(v) for v in value]
    return value


def records(run: Path, policy: str) -> dict[tuple[str, int], dict]:
    out = {}
    for line in (run / "episodes.jsonl").read_text().splitlines():
        record = json.loads(line)
        if record.get("policy") == policy and "metrics" in record:
            out[(record["case_id"], int(record["seed"]))] = untimed(record)
    return out


def first_difference(a: dict, b: dict) -> str:
    """Where two records first part: the first step that differs, else the first key."""
    for n, (x, y) in enumerate(zip(a.get("steps", []), b.get("steps", []))):
        if x != y:
            return f"step {n}"
    for key in sorted(set(a) | set(b)):
        if a.get(key) != b.get(key):
            return key
    return "-"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for(url: str, service: subprocess.Popen, timeout_s: float = 120.0) -> None:
    import httpx

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if service.poll() is not None:
            raise SystemExit(f"the cell service exited with code {service.returncode}")
        try:
            if httpx.get(f"{url}/v1/health", timeout=2.0).status_code == 200:
                return
        except httpx.HTTPError:
            time.sleep(0.5)
    raise SystemExit(f"no cell service answered at {url} within {timeout_s:.0f} s")


def bench_args(config: dict, policy: str, out: Path, url: str) -> list[str]:
    sensing = config.get("sensing", {})
    origin = str(config["cases_origin"])
    cases = origin.removeprefix("suite:")  # a bundled suite by name, else the path as given
    args = [
        "packlab", "bench", "--cases", cases,
        "--policies", policy, "--seeds", ",".join(map(str, config["seeds"])),
        "--observation", "perceived", "--execution", "noisy",
        "--noise", str(sensing.get("noise", "structured-light")),
        "--out", str(out), "--via-cell", url, "--no-html", "--no-figures",
    ]  # fmt: skip
    if "size_prior" in sensing:
        args += ["--size-prior", str(sensing["size_prior"])]
    return args


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--in-process", type=Path, required=True, help="honest run directory")
    parser.add_argument("--policy", default="plan-fast")
    parser.add_argument("--out", type=Path, default=Path("runs/via-cell-records"))
    args = parser.parse_args()
    config = json.loads((args.in_process / "config.json").read_text())
    if config.get("sensing", {}).get("observation") != "perceived":
        raise SystemExit(f"{args.in_process}/config.json: observation is not perceived")
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    serve = ["packlab", "cell", "serve", "--policy", args.policy, "--port", str(port)]
    service = subprocess.Popen(serve, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for(url, service)
        started = time.monotonic()
        command = bench_args(config, args.policy, args.out, url)
        print("+", " ".join(command), file=sys.stderr, flush=True)
        subprocess.run(command, check=True)
        via_wall = time.monotonic() - started
    finally:
        service.terminate()
        service.wait(timeout=30)
    here, there = records(args.in_process, args.policy), records(args.out, args.policy)
    common = sorted(set(here) & set(there))
    differing = [(k, first_difference(here[k], there[k])) for k in common if here[k] != there[k]]

    def mean_overall(recs: dict) -> float:
        return sum(recs[k]["metrics"]["overall"] for k in common) / max(len(common), 1)

    print(f"load average {os.getloadavg()[0]:.1f}; via-cell run {via_wall:.0f} s wall")
    print(f"episodes compared: {len(common)} (in-process {len(here)}, via cell {len(there)})")
    print(f"identical records: {len(common) - len(differing)}")
    print(f"differing records: {len(differing)}")
    for (case, seed), where in differing[:20]:
        print(f"  {case} seed {seed}: first differs at {where}")
    print(f"mean Overall: in-process {mean_overall(here):.4f}, via cell {mean_overall(there):.4f}")


if __name__ == "__main__":
    main()
