"""The results tables of the README and of docs/results/index.md, written from bench records.

Each table is one ``packlab bench`` run. Its summary (``summary.json``, with the per-case scores
the intervals are drawn from), its ``config.json`` and a stamp (the command, the commit the
records were made at, the date, the machine, the wall time) are kept under ``results/<table>/``,
so the pages can be rebuilt from the repository without rerunning anything:

    python benchmarks/results_tables.py                  # rewrite the pages from results/
    python benchmarks/results_tables.py --run            # run (or resume) every table first
    python benchmarks/results_tables.py --run --only packlab-bench-v1

``--run`` runs the bench into ``runs/results/<table>`` (resumable: rerun the same command after a
crash), then copies the three small files into ``results/<table>/``. A run is refused when its
records were begun at another commit than the tree's (the stamp would lie); ``--restart``
deletes such a run. The README's table sits between two marker lines and is replaced in place.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import date
from pathlib import Path

from packlab.bench.compare import differences_markdown, load_summary
from packlab.bench.summary import run_intervals
from packlab.bench.table import interval_note, results_table
from packlab.bench.terminal import compact_rows

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
RUNS = ROOT / "runs" / "results"
PAGE = ROOT / "docs" / "results" / "index.md"
README = ROOT / "README.md"
README_START = "<!-- results:start (written by benchmarks/results_tables.py) -->"
README_END = "<!-- results:end -->"
THIS = "python benchmarks/results_tables.py"
STAMP = "stamp.json"
KEPT = ("config.json", "summary.json", STAMP)

ROWS = "dblf,hm,mta,ffp,sdf,plan-fast,vlm,irbpp,tapnet,random,oracle"


@dataclass(frozen=True)
class Table:
    """One results table: a ``packlab bench`` run and how the page introduces it."""

    name: str  # the anchor on the results page and the folder under results/
    title: str
    bench_args: tuple[str, ...]
    about: str
    reference: str = "plan-fast"  # paired differences are against this row


TABLES = (
    Table(
        "packlab-bench-v1",
        "packlab-bench-v1 (the main table)",
        (),
        "`packlab bench` on its bundled defaults: the suite packlab-bench-v1 (60 layered cases, "
        "20 per level; buffer 3 / 5 / 10 for easy / medium / hard; boxes arrive after their "
        "supports, layers interleaved), the default rows, 3 seeds, MuJoCo, exact observations.",
    ),
    Table(
        "packlab-bench-layers-v1",
        "packlab-bench-layers-v1 (layer order)",
        ("--cases", "packlab-bench-layers-v1"),
        "The same recipe with the reference's arrival order: layer by layer, shuffled within a "
        "layer.",
    ),
    Table(
        "packlab-bench-cut-v1",
        "packlab-bench-cut-v1 (cut layouts)",
        ("--cases", "packlab-bench-cut-v1", "--policies", f"plan,{ROWS}"),
        "Cut layouts (the stack cut recursively: boxes of many heights, no flat layers) arriving "
        "in their support order. `plan` is added to the default rows.",
    ),
    Table(
        "robot-path-structured-light",
        "Robot path: perceived, noisy, structured light",
        (
            "--observation",
            "perceived",
            "--execution",
            "noisy",
            "--noise",
            "structured-light",
            "--policies",
            ROWS.removesuffix(",oracle"),
        ),
        "packlab-bench-v1 as a robot cell sees and acts: depth cameras with a structured-light "
        "noise model, boxes segmented from depth (no simulator masks), noisy execution with the "
        "guarded place skill, missed boxes set aside. Every figure here is one a robot could "
        "produce, given the priors a cell has: box sizes on the size grid (lengths and widths in "
        "25 mm steps, heights in 2 mm), the buffer's count, the count still to come, the "
        "payload's weight and camera calibration ([the robot path](../perception.md)). The "
        "oracle needs the true layout and is left out.",
    ),
)


def git_commit() -> tuple[str, bool]:
    """The tree's commit and whether files that the bench imports differ from it."""
    head = subprocess.run(
        ["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.strip()
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--", "src", "pyproject.toml"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    return head, bool(dirty)


def bench_command(table: Table) -> list[str]:
    return ["packlab", "bench", *table.bench_args]


def run_table(table: Table, restart: bool) -> None:
    """Run (or resume) one table's bench into runs/results/<name>, then keep its small files."""
    run_dir = RUNS / table.name
    commit, dirty = git_commit()
    stamp_path = run_dir / STAMP
    if stamp_path.is_file():
        stamp = json.loads(stamp_path.read_text(encoding="utf-8"))
        if stamp["commit"] != commit and not restart:
            sys.exit(
                f"{stamp_path}: records begun at commit {stamp['commit'][:12]}, the tree is at "
                f"{commit[:12]}; rerun with --restart to delete that run and start again"
            )
        if stamp["commit"] != commit:
            shutil.rmtree(run_dir)
    if dirty:
        print(f"warning: src/ differs from {commit[:12]}; the stamp says so", file=sys.stderr)
    run_dir.mkdir(parents=True, exist_ok=True)
    if not stamp_path.is_file():
        stamp = {
            "command": " ".join(bench_command(table)),
            "commit": commit,
            "dirty": dirty,
            "date": date.today().isoformat(),
            "machine": f"{os.cpu_count()} CPU cores, {platform.system()} {platform.machine()}",
            "wall_s": 0.0,
            "note": "",
        }
        stamp_path.write_text(json.dumps(stamp, indent=1) + "\n", encoding="utf-8")
    stamp = json.loads(stamp_path.read_text(encoding="utf-8"))
    t0 = time.monotonic()
    cmd = [*bench_command(table), "--out", str(run_dir), "--no-html", "--no-figures"]
    print("+", " ".join(cmd), flush=True)
    done = subprocess.run(cmd, cwd=ROOT, check=False)
    stamp["wall_s"] = round(stamp.get("wall_s", 0.0) + time.monotonic() - t0, 1)
    stamp_path.write_text(json.dumps(stamp, indent=1) + "\n", encoding="utf-8")
    if done.returncode != 0:
        sys.exit(f"{' '.join(cmd)} exited {done.returncode}; rerun to resume")
    keep = RESULTS / table.name
    keep.mkdir(parents=True, exist_ok=True)
    for name in KEPT:
        shutil.copyfile(run_dir / name, keep / name)


def stamp_line(table: Table, stamp: dict) -> str:
    minutes = stamp.get("wall_s", 0.0) / 60
    wall = f", {minutes:.1f} min wall time" if minutes else ""
    dirty = " plus uncommitted changes to src/" if stamp.get("dirty") else ""
    if stamp.get("note"):  # e.g. the machine was shared, so the wall time is an upper bound
        wall += f"; {stamp['note']}"
    return (
        f"Produced by `{THIS}` from the records of `{stamp['command']}` "
        f"at commit `{stamp['commit'][:12]}`{dirty} on {stamp['date']} "
        f"({stamp['machine']}{wall})."
    )


def _markdown_rows(rows: list[list[str]]) -> str:
    head, *body = rows
    lines = [
        "| " + " | ".join(head) + " |",
        "|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|",
    ]
    lines += ["| " + " | ".join(r) + " |" for r in body]
    return "\n".join(lines)


def compact_markdown(table: Table) -> tuple[str, dict]:
    keep = RESULTS / table.name
    summary = load_summary(keep)
    stamp = json.loads((keep / STAMP).read_text(encoding="utf-8"))
    return _markdown_rows(compact_rows(summary, run_intervals(summary))), stamp


def page_section(table: Table) -> str:
    keep = RESULTS / table.name
    summary = load_summary(keep)
    intervals = run_intervals(summary)
    stamp = json.loads((keep / STAMP).read_text(encoding="utf-8"))
    compact = _markdown_rows(compact_rows(summary, intervals))
    reference = table.reference if table.reference in summary.policies else None
    diffs = differences_markdown(summary, reference) if reference else ""
    return "\n\n".join(
        part
        for part in (
            f"## {table.title} {{#{table.name}}}",
            table.about,
            stamp_line(table, stamp),
            compact,
            "Every level, with Success Ratio and Compactness:",
            results_table(summary, intervals=intervals),
            interval_note(summary, intervals),
            diffs,
        )
        if part
    )


def write_page() -> None:
    sections = [page_section(t) for t in TABLES if (RESULTS / t.name / "summary.json").is_file()]
    reproduce = "\n".join(f"    {' '.join(bench_command(t))}   # {t.name}" for t in TABLES)
    text = f"""# Current results

Every table on this page (and the table in the README) is written by `{THIS}` from bench
records kept in the repository under `results/`; each says which command made its records, at
which commit, when and on what machine. Scores are the mean over 3 seeds with a 95 % bootstrap
interval over cases in brackets; two rows differ only where their paired interval excludes zero.
What the metrics mean: [Running the benchmark](../benchmark.md). Where packlab still falls
short: [Known limits](../limits.md). Earlier tables and the measured attempts that did not ship:
the history of the [planner](../history/planner.md), the [RL agents](../history/rl.md), the
[packing VLM](../history/vlm.md), the [robot path](../history/perception.md), the
[benchmark tables](../history/bench.md) and the [protocols](../history/protocols.md).

{chr(10).join(s + chr(10) for s in sections)}
## How to reproduce

Each table is one `packlab bench` run (a few minutes to half an hour each on 2 cores; rerun a
command to resume it):

{reproduce}

`{THIS} --run` runs them all (or `--only NAME` one) into `runs/results/`, keeps each run's
`summary.json`, `config.json` and stamp under `results/`, and rewrites this page and the README's
table. `{THIS}` alone rewrites both from `results/`.
"""
    PAGE.parent.mkdir(parents=True, exist_ok=True)
    PAGE.write_text(text, encoding="utf-8")


def write_readme() -> None:
    table = TABLES[0]
    if not (RESULTS / table.name / "summary.json").is_file():
        return
    compact, stamp = compact_markdown(table)
    block = "\n\n".join((README_START, compact, stamp_line(table, stamp), README_END))
    text = README.read_text(encoding="utf-8")
    if README_START not in text or README_END not in text:
        sys.exit(f"{README}: no results markers ({README_START!r} ... {README_END!r})")
    head, rest = text.split(README_START, 1)
    _, tail = rest.split(README_END, 1)
    README.write_text(head + block + tail, encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="store_true", help="run (or resume) the bench runs first")
    parser.add_argument("--only", help="comma-separated table names (default: all)")
    parser.add_argument(
        "--restart", action="store_true", help="delete a run begun at another commit"
    )
    args = parser.parse_args(argv)
    names = {t.name for t in TABLES}
    chosen = set(args.only.split(",")) if args.only else names
    if chosen - names:
        parser.error(
            f"--only: unknown table(s) {sorted(chosen - names)}; choose from {sorted(names)}"
        )
    if args.run:
        for table in TABLES:
            if table.name in chosen:
                run_table(table, args.restart)
    write_page()
    write_readme()
    print(f"wrote {PAGE.relative_to(ROOT)} and the README's table")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
