"""How far off the bench's estimate of the time left is, counting episodes or boxes.

Replays a finished run's episodes (their recorded ``episode_s``) in the order the runner hands
them out (most boxes first) over N workers, and prints, at a few points of the run, the true time
left beside the estimate a progress bar makes from the average rate so far, counted in episodes
and in boxes placed:

    python benchmarks/maintainers/progress_estimate.py runs/bench-packlab-bench-v1 --workers 2
"""

from __future__ import annotations

import argparse
import heapq
from pathlib import Path

from packlab.bench.records import read_records
from packlab.core.records import EpisodeOk


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", help="a finished bench run directory")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    records = [
        r for r in read_records(Path(args.run_dir) / "episodes.jsonl") if isinstance(r, EpisodeOk)
    ]
    work = sorted(((len(r.steps), r.timing.episode_s) for r in records), key=lambda w: -w[0])
    free = [0.0] * args.workers  # when each worker is next free
    finished = []
    for boxes, seconds in work:
        start = heapq.heappop(free)
        heapq.heappush(free, start + seconds)
        finished.append((start + seconds, boxes))
    finished.sort()
    wall, n, total_boxes = finished[-1][0], len(finished), sum(b for _, b in finished)
    print(f"{n} episodes, {total_boxes} boxes, {args.workers} workers: {wall / 60:.1f} min\n")
    print("| elapsed (min) | true time left | estimate, episodes | estimate, boxes |")
    print("|---:|---:|---:|---:|")
    for share in (0.05, 0.1, 0.2, 0.3, 0.5):
        t = share * wall
        eps = sum(1 for end, _ in finished if end <= t)
        boxes = sum(b for end, b in finished if end <= t)
        by_eps = t * (n - eps) / eps / 60 if eps else float("nan")
        by_boxes = t * (total_boxes - boxes) / boxes / 60 if boxes else float("nan")
        print(f"| {t / 60:.1f} | {(wall - t) / 60:.1f} | {by_eps:.1f} | {by_boxes:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
