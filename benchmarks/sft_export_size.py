"""SFT export size and tokens: one conversation per episode against one example per step.

Generates a dataset with PackData-20K's mix scaled down (``--episodes`` split 9000:7000:4000,
geometric validation, the 20K recipe's user seed: training seed domain), then measures the disk
bytes of (a) the ``hf`` export (``sft/*.parquet``, PNGs embedded), (b) the ``verl`` export
(image paths), (c) the old per-step JSONL export (image paths), written by the code of a
baseline revision checked out in a temporary ``git worktree`` and run in a subprocess, and
(d) the ``images/`` directory they refer to. Each is given per step and extrapolated to
PackData-20K per difficulty (its episode counts times this run's mean steps per episode).

The second table counts the tokens of the hard episodes with the project tokenizer (chat
template text plus each image's visual tokens, :mod:`packlab.vlm.data.sft_tokens`): the new
export encodes each episode once; the old one encoded, for every step, the whole history in
front of it and its answer, i.e. the episode's conversation up to that answer. Those prefix
lengths are read off one encoding of the new conversation (``turn_end_tokens``), and checked
against the old JSONL's own examples tokenized directly.

    python benchmarks/sft_export_size.py                      # 200 episodes, default --baseline
    python benchmarks/sft_export_size.py --episodes 40 --keep /tmp/sft-size
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from PIL import Image

from packlab.datagen.config import RECIPES, DatasetConfig, ValidationConfig
from packlab.datagen.engine import RunOptions, generate_dataset
from packlab.datagen.sft_export import export_sft
from packlab.vlm.data import sft_tokens

REPO = Path(__file__).resolve().parents[1]
RECIPE = RECIPES["packdata-20k"]
DIFFICULTIES = RECIPE.difficulties
#: The old export's entry point at the baseline revision, run with PYTHONPATH=<worktree>/src.
OLD_EXPORT = (
    "import sys; from packlab.datagen.format import export_sft; export_sft(sys.argv[1], 'per_step')"
)


def scaled_episodes(total: int) -> tuple[int, ...]:
    """``total`` episodes split in PackData-20K's proportions (9000:7000:4000)."""
    full = sum(RECIPE.episodes)
    counts = [round(total * n / full) for n in RECIPE.episodes]
    counts[0] += total - sum(counts)  # rounding leftovers go to the largest group
    return tuple(counts)


def make_dataset(out: Path, episodes: tuple[int, ...], seed: int, image_size: int) -> Path:
    """A dataset of the 20K mix on the fast path (geometric replay; the export as generated)."""
    cfg = DatasetConfig(
        DIFFICULTIES,
        episodes,
        seed=seed,
        image_size=image_size,
        validation=ValidationConfig(backend="geometric"),
    )
    generate_dataset(cfg, RunOptions(str(out), workers=1, progress=False))
    return out


@contextlib.contextmanager
def baseline_worktree(revision: str) -> Iterator[Path | None]:
    """A temporary ``git worktree`` of ``revision`` of this repository, removed afterwards;
    None (with a note on stderr) where git or the revision is not there."""
    if shutil.which("git") is None:
        print("note: git is not installed; the baseline is skipped", file=sys.stderr)
        yield None
        return
    tmp = Path(tempfile.mkdtemp(prefix="packlab-baseline-"))
    path = tmp / "src-tree"
    add = ["git", "-C", str(REPO), "worktree", "add", "--detach", str(path), revision]
    done = subprocess.run(add, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        print(f"note: no worktree of {revision}: {done.stderr.strip()}", file=sys.stderr)
        shutil.rmtree(tmp, ignore_errors=True)
        yield None
        return
    try:
        yield path
    finally:
        remove = ["git", "-C", str(REPO), "worktree", "remove", "--force", str(path)]
        subprocess.run(remove, capture_output=True, check=False)
        shutil.rmtree(tmp, ignore_errors=True)


def baseline_env(worktree: Path) -> dict[str, str]:
    """The environment that runs the baseline's packlab instead of the installed one."""
    return {**os.environ, "PYTHONPATH": str(worktree / "src")}


def old_export(worktree: Path, dataset: Path, dest: Path) -> Path:
    """``dest``: a copy of ``dataset`` (steps, images, meta; no export) with the baseline's
    per-step JSONL export written by the baseline's own code into ``dest/sft``."""
    shutil.copytree(dataset, dest, ignore=shutil.ignore_patterns("sft", "sft-verl"))
    cmd = [sys.executable, "-c", OLD_EXPORT, str(dest)]
    subprocess.run(cmd, env=baseline_env(worktree), check=True, cwd=dest)
    return dest


def file_bytes(files: list[Path]) -> int:
    return sum(p.stat().st_size for p in files)


def bytes_by_difficulty(directory: Path, pattern: str) -> dict[str, int]:
    """Bytes of an export's files per difficulty (shard files are named ``<difficulty>-N``)."""
    return {
        d: file_bytes([p for p in directory.glob(pattern) if p.name.startswith(f"{d}-")])
        for d in DIFFICULTIES
    }


def images_by_difficulty(root: Path) -> dict[str, int]:
    return {d: file_bytes([p for p in (root / "images" / d).rglob("*.png")]) for d in DIFFICULTIES}


def step_counts(root: Path) -> tuple[dict[str, int], dict[str, int]]:
    """(episodes, steps) per difficulty from the dataset's info.json."""
    info = json.loads((root / "meta" / "info.json").read_text())["counts"]["by_difficulty"]
    return (
        {d: int(info[d]["episodes"]) for d in DIFFICULTIES},
        {d: int(info[d]["steps"]) for d in DIFFICULTIES},
    )


def steps_20k(episodes: dict[str, int], steps: dict[str, int]) -> dict[str, float]:
    """PackData-20K's steps per difficulty: its episodes times this run's mean steps."""
    return {
        d: n * steps[d] / episodes[d] for d, n in zip(DIFFICULTIES, RECIPE.episodes) if episodes[d]
    }


def _human(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if abs(n) < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.2f} {unit}"
        n /= 1000
    return f"{n:.2f} TB"


def size_rows(
    sizes: dict[str, dict[str, int]], steps: dict[str, int], full: dict[str, float]
) -> list[list[str]]:
    """One table row per measured export: bytes, per step, extrapolated, against the old."""
    total_steps = sum(steps.values())
    old = sizes.get("old per-step JSONL")
    old_20k = sum(old[d] / steps[d] * full[d] for d in full) if old else None
    rows = []
    for name, by in sizes.items():
        total = sum(by.values())
        at_20k = sum(by[d] / steps[d] * full[d] for d in full)
        ratio = f"{at_20k / old_20k:.3f}" if old_20k and name != "images/ (reference)" else "-"
        rows.append(
            [
                name,
                f"{total:,}",
                f"{total / total_steps:,.0f}",
                _human(at_20k),
                ratio,
            ]
        )
    return rows


def markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def measure_sizes(root: Path, old_root: Path | None) -> dict[str, dict[str, int]]:
    """Bytes per difficulty of each export (and of the images), in table order."""
    export_sft(root, "verl")
    sizes = {
        "new hf (sft/*.parquet, PNGs embedded)": bytes_by_difficulty(root / "sft", "*.parquet"),
        "verl (sft-verl/*.parquet, image paths)": bytes_by_difficulty(
            root / "sft-verl", "*.parquet"
        ),
    }
    if old_root is not None:
        sizes["old per-step JSONL"] = bytes_by_difficulty(old_root / "sft", "*.jsonl")
    sizes["images/ (reference)"] = images_by_difficulty(root)
    return sizes


def old_examples(old_root: Path, difficulty: str) -> list[sft_tokens.Conversation]:
    """The old JSONL's examples of ``difficulty`` as conversations (their images' sizes read
    from the PNG files they name)."""
    sizes: dict[str, tuple[int, int]] = {}
    out = []
    for path in sorted((old_root / "sft").glob(f"{difficulty}-*.jsonl")):
        for line in path.read_text().splitlines():
            row = json.loads(line)
            content = [c for m in row["messages"] for c in m["content"]]
            names = [c["image"] for c in content if c["type"] == "image"]
            for name in names:
                if name not in sizes:
                    with Image.open(old_root / name) as im:
                        sizes[name] = im.size
            images = [sizes[n] for n in names]
            out.append(
                sft_tokens.Conversation(row["episode_id"], difficulty, 0, row["messages"], images)
            )
    return out


def token_rows(root: Path, old_root: Path | None, difficulty: str) -> tuple[list[list[str]], str]:
    """(rows of the token table, the lines under it) for the episodes of ``difficulty``."""
    counter = sft_tokens.project_counter()
    files = sft_tokens.export_files(root)
    wanted = {
        r["episode_id"] for r in sft_tokens.read_index(files) if r["difficulty"] == difficulty
    }
    convs = sft_tokens.whole_episodes(sft_tokens.read_conversations(files, wanted))
    actions = sum(sum(m["role"] == "assistant" for m in c.messages) for c in convs)
    once = sum(counter.count(c) for c in convs)
    # Old example of step t = the conversation through answer t: its prefix's tokens.
    old = sum(sum(counter.turn_end_tokens(c)) for c in convs)
    rows = [
        ["new: one conversation per episode", actions, once, once / actions, 1.0],
        ["old: one example per step (prefix sums)", actions, old, old / actions, old / once],
    ]
    table = [[r[0], f"{r[1]:,}", f"{r[2]:,}", f"{r[3]:.1f}", f"{r[4]:.2f}"] for r in rows]
    table.append(["ratio new/old", "", f"{once / old:.3f}", f"{once / old:.3f}", ""])
    image = ", ".join(f"{w}x{h} px: {n}" for (w, h), n in sorted(counter.image_tokens.items()))
    lines = [f"tokenizer {counter.name}; images as {counter.family} ({image} visual tokens)"]
    if old_root is not None:
        direct = [counter.count(c) for c in old_examples(old_root, difficulty)]
        lines.append(
            f"check: the old JSONL's {len(direct):,} {difficulty} examples tokenized directly: "
            f"{sum(direct):,} tokens (prefix sums: {old:,})"
        )
    return table, "\n".join(lines)


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--episodes", type=int, default=200, help="episodes in all, split 9000:7000:4000"
    )
    ap.add_argument("--seed", type=int, default=RECIPE.seed, help="user seed (training domain)")
    ap.add_argument("--image-size", type=int, default=224)
    ap.add_argument("--baseline", default="c941aee", help="revision of the old export")
    ap.add_argument("--token-difficulty", default="hard", choices=DIFFICULTIES)
    ap.add_argument("--keep", metavar="DIR", help="write the datasets here and keep them")
    return ap.parse_args()


def report(args: argparse.Namespace, work: Path, worktree: Path | None) -> None:
    episodes = scaled_episodes(args.episodes)
    root = make_dataset(work / "data", episodes, args.seed, args.image_size)
    old_root = old_export(worktree, root, work / "old") if worktree is not None else None
    n_episodes, steps = step_counts(root)
    full = steps_20k(n_episodes, steps)
    print(
        f"dataset: {dict(zip(DIFFICULTIES, episodes))} episodes (seed {args.seed}, geometric, "
        f"{args.image_size} px), {sum(steps.values())} steps; mean steps per episode "
        + ", ".join(f"{d} {steps[d] / n_episodes[d]:.2f}" for d in DIFFICULTIES if n_episodes[d])
        + f"; PackData-20K at these means: {sum(full.values()):,.0f} steps"
    )
    print(f"baseline: {args.baseline}" + ("" if worktree else " (skipped)"))
    print()
    header = ["export", "bytes", "bytes/step", "PackData-20K (extrapolated)", "vs old (20K)"]
    print(markdown(header, size_rows(measure_sizes(root, old_root), steps, full)))
    print()
    rows, note = token_rows(root, old_root, args.token_difficulty)
    header = [
        f"{args.token_difficulty} episodes",
        "labelled actions",
        "tokens encoded",
        "tokens / labelled action",
        "encoding passes",
    ]
    print(markdown(header, rows))
    print(note)


def work_dir(stack: contextlib.ExitStack, keep: str | None, prefix: str) -> Path:
    """``--keep DIR`` (new, kept afterwards) or a temporary directory removed with ``stack``."""
    if not keep:
        return Path(stack.enter_context(tempfile.TemporaryDirectory(prefix=prefix)))
    work = Path(keep)
    if work.exists():
        raise SystemExit(f"--keep {work}: exists; give a new directory")
    work.mkdir(parents=True)
    return work


def main() -> None:
    args = parse_args()
    with contextlib.ExitStack() as stack:
        work = work_dir(stack, args.keep, "sft-size-")
        worktree = stack.enter_context(baseline_worktree(args.baseline))
        report(args, work, worktree)


if __name__ == "__main__":
    main()
