"""Time and size of report.html (the interactive bench report) for existing run directories.

Usage:
    python benchmarks/maintainers/report_build_time.py     # runs/bench-packlab-bench-v1
    python benchmarks/maintainers/report_build_time.py RUN_DIR [RUN_DIR ...] --repeat 3

For each run it builds the page as ``packlab bench report DIR --html`` does, into a scratch
file (the run directory is not touched), and prints one row: episodes, size of episodes.jsonl,
the time of each phase (best of ``--repeat``: read the files, summarise, build the page's data,
render the HTML) and the page's size, split into plotly.js and the embedded data. The target
for the default bench (60 cases x 3 seeds x 8 methods) is under 10 s and under 20 MB.

The machine may be shared: the load average at start is printed with the table.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections import Counter
from pathlib import Path

from packlab.bench.html_report import run_html
from packlab.bench.report import load_run, summary_of
from packlab.viz.report_html import embedded_data, plotly_js

DEFAULT_RUN = Path("runs/bench-packlab-bench-v1")
MB = 1024 * 1024


def _best(fn, repeat: int):
    """(best wall seconds, last result) of ``fn()`` over ``repeat`` calls."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def measure(run_dir: Path, repeat: int) -> dict[str, object]:
    load_s, run = _best(lambda: load_run(run_dir), repeat)
    summary_s, summary = _best(lambda: summary_of(run.config, run.records), repeat)
    page_s, html = _best(
        lambda: run_html(run.config, run.records, run.cases, summary, generated="-"), repeat
    )
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "report.html"
        write_s, _ = _best(lambda: out.write_text(html, encoding="utf-8"), repeat)
        size = out.stat().st_size
    data = embedded_data(html)
    sources = Counter(e.get("poses", "error") for e in data["episodes"])
    return {
        "run": str(run_dir),
        "episodes": len(run.records),
        "methods": len(data["methods"]),
        "records_mb": (run_dir / "episodes.jsonl").stat().st_size / MB,
        "load_s": load_s,
        "summary_s": summary_s,
        "page_s": page_s,
        "write_s": write_s,
        "total_s": load_s + summary_s + page_s + write_s,
        "html_mb": size / MB,
        "plotly_mb": len(plotly_js().encode()) / MB,
        "sources": ", ".join(f"{k} {v}" for k, v in sorted(sources.items())),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("runs", nargs="*", type=Path, help=f"run directories (default {DEFAULT_RUN})")
    ap.add_argument("--repeat", type=int, default=3, help="builds per run; the best is shown")
    args = ap.parse_args()
    runs = args.runs or [DEFAULT_RUN]
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    head = (
        f"{'run':<44}{'episodes':>9}{'methods':>8}{'records MB':>11}{'read s':>8}"
        f"{'summary s':>10}{'page s':>8}{'write s':>8}{'total s':>8}{'HTML MB':>8}"
        f"{'plotly MB':>10}"
    )
    print(head)
    print("-" * len(head))
    rows = [measure(r, args.repeat) for r in runs]
    for m in rows:
        print(
            f"{str(m['run'])[-43:]:<44}{m['episodes']:>9}{m['methods']:>8}{m['records_mb']:>11.1f}"
            f"{m['load_s']:>8.2f}{m['summary_s']:>10.2f}{m['page_s']:>8.2f}{m['write_s']:>8.2f}"
            f"{m['total_s']:>8.2f}{m['html_mb']:>8.1f}{m['plotly_mb']:>10.1f}"
        )
    for m in rows:
        print(f"{m['run']}: replay poses per episode: {m['sources']}")


if __name__ == "__main__":
    main()
