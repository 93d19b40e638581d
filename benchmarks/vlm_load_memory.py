"""Peak memory and time of building a 2B-class Qwen3-VL in fp32 and in bf16.

Usage: python benchmarks/vlm_load_memory.py [--config 2b|small]

Writes the chosen config (below) as a directory holding only its config.json, then builds
``make_model("config:DIR", dtype=...)`` (random weights, the project's tokenizer) in a fresh
Python process per dtype, so that each peak is the build's own. A process's peak resident set
(``ru_maxrss``) counts its imports too, so a process that only imports torch, transformers and
packlab is measured the same way and its peak subtracted. Prints a markdown table: parameters,
the weights' own size, peak RSS over that baseline, wall seconds of ``make_model``, and the
bf16/fp32 ratios. ``small`` (about 100 M parameters) is for quick runs.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# Qwen3-VL-2B-Instruct's dimensions as published in its config.json on the Hugging Face hub,
# entered here by hand (no download); every field not given takes transformers' Qwen3VLConfig
# default (rope settings among them: they change no parameter count or memory).
QWEN3_VL_2B = {
    "model_type": "qwen3_vl",
    "tie_word_embeddings": True,
    "text_config": {
        "hidden_size": 2048,
        "num_hidden_layers": 28,
        "num_attention_heads": 16,
        "num_key_value_heads": 8,
        "head_dim": 128,
        "intermediate_size": 6144,
        "vocab_size": 151936,
        "tie_word_embeddings": True,
    },
    "vision_config": {
        "depth": 24,
        "hidden_size": 1024,
        "num_heads": 16,
        "intermediate_size": 4096,
        "out_hidden_size": 2048,
        "patch_size": 16,
        "spatial_merge_size": 2,
        "temporal_patch_size": 2,
        "deepstack_visual_indexes": [5, 11, 17],
    },
}

# The same classes at about 100 M parameters (most of them the full vocabulary's embedding).
QWEN3_VL_SMALL = {
    "model_type": "qwen3_vl",
    "tie_word_embeddings": True,
    "text_config": {
        "hidden_size": 512,
        "num_hidden_layers": 8,
        "num_attention_heads": 8,
        "num_key_value_heads": 4,
        "head_dim": 64,
        "intermediate_size": 1536,
        "vocab_size": 151936,
        "tie_word_embeddings": True,
    },
    "vision_config": {
        "depth": 4,
        "hidden_size": 256,
        "num_heads": 4,
        "intermediate_size": 1024,
        "out_hidden_size": 512,
        "patch_size": 16,
        "spatial_merge_size": 2,
        "temporal_patch_size": 2,
        "deepstack_visual_indexes": [1, 2, 3],
    },
}

CONFIGS = {"2b": QWEN3_VL_2B, "small": QWEN3_VL_SMALL}
DTYPES = ("fp32", "bf16")
BYTES = {"fp32": 4, "bf16": 2}
GIB = 1024**3


def peak_rss_bytes() -> int:
    """This process's peak resident set (Linux reports ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def child(what: str, config_dir: str) -> dict:
    """Run in the fresh process: import, then (unless ``baseline``) build the model."""
    import torch  # noqa: F401  (the baseline's imports are the build's imports)
    import transformers  # noqa: F401

    from packlab.vlm.model.checkpoint import TORCH_DTYPES, count_parameters
    from packlab.vlm.model.spec import make_model

    if what == "baseline":
        return {"peak": peak_rss_bytes()}
    t0 = time.perf_counter()
    vlm = make_model(f"config:{config_dir}", dtype=what)
    seconds = time.perf_counter() - t0
    dtypes = {p.dtype for p in vlm.model.parameters()}
    if dtypes != {TORCH_DTYPES[what]}:
        raise SystemExit(f"{what}: parameters came out in {dtypes}")
    return {"peak": peak_rss_bytes(), "params": count_parameters(vlm.model), "seconds": seconds}


def measure(what: str, config_dir: str) -> dict:
    """:func:`child` in a fresh interpreter; its JSON answer is the last line of its output."""
    out = subprocess.run(
        [sys.executable, __file__, "--child", what, "--dir", config_dir],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def table(config_name: str, base: dict, rows: dict[str, dict]) -> str:
    fp32, bf16 = rows["fp32"], rows["bf16"]
    over = {k: r["peak"] - base["peak"] for k, r in rows.items()}
    title = (
        f"Qwen3-VL `{config_name}` config, `make_model('config:DIR', dtype=...)`, "
        f"baseline (imports only) peak RSS {base['peak'] / GIB:.2f} GiB"
    )
    lines = [
        title,
        "",
        "| dtype | parameters | weights (GiB) | peak RSS over baseline (GiB) | wall (s) |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, r in rows.items():
        weights = r["params"] * BYTES[name] / GIB
        lines.append(
            f"| {name} | {r['params']:,} | {weights:.2f} | {over[name] / GIB:.2f} "
            f"| {r['seconds']:.1f} |"
        )
    lines.append(
        f"| bf16/fp32 | | {BYTES['bf16'] / BYTES['fp32']:.2f} | "
        f"{over['bf16'] / over['fp32']:.2f} | {bf16['seconds'] / fp32['seconds']:.2f} |"
    )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", choices=tuple(CONFIGS), default="2b")
    ap.add_argument("--child", choices=("baseline", *DTYPES), help=argparse.SUPPRESS)
    ap.add_argument("--dir", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.dir)))
        return
    import torch
    import transformers

    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "config.json").write_text(json.dumps(CONFIGS[args.config], indent=1))
        base = measure("baseline", tmp)
        rows = {name: measure(name, tmp) for name in DTYPES}
    print(table(args.config, base, rows))
    print(
        f"\n{platform.platform()}, {platform.processor() or platform.machine()}, "
        f"torch {torch.__version__}, transformers {transformers.__version__}, "
        f"{torch.get_num_threads()} threads"
    )


if __name__ == "__main__":
    main()
