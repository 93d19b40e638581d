"""What ``packlab inspect-data`` does (:mod:`packlab.cli.inspect_data` defines its flags and
imports this module when it runs)."""

from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path
from types import ModuleType
from typing import Any

from packlab.core.errors import ConfigError
from packlab.core.records import to_builtins
from packlab.datagen.format import read_info
from packlab.datagen.stats import collect, dataset_cases, format_report, save_histograms

#: Token figures of the SFT export: the project tokenizer and an image processor, so the vlm
#: extra; imported only when asked, and its absence is a line of the report, not an error.
TOKENS_MODULE = "packlab.vlm.data.sft_tokens"


def _tokens_module() -> tuple[ModuleType | None, str]:
    """The token module, or None and the one line that says why not."""
    try:
        return importlib.import_module(TOKENS_MODULE), ""
    except ImportError as exc:
        missing = getattr(exc, "name", None) or str(exc)
        return None, (
            f"SFT export tokens: not measured (needs the vlm extra, pip install "
            f"'packlab[vlm]'; {missing} is missing)"
        )


def sft_tokens(args: argparse.Namespace) -> tuple[dict[str, Any] | None, str]:
    """(figures as JSON-ready dict or None, the text to print) of the SFT export's tokens."""
    if args.token_sample < 0:
        raise ConfigError(f"token_sample = {args.token_sample}: must be >= 0 (0: none)")
    if args.token_sample == 0:
        return None, ""
    module, why_not = _tokens_module()
    if module is None:
        return None, why_not
    if not module.export_files(args.dir):
        return None, "SFT export tokens: no sft/*.parquet (write it: packlab export sft DIR)"
    counter = (
        module.checkpoint_counter(args.tokenizer) if args.tokenizer else module.project_counter()
    )
    report = module.measure(args.dir, counter, args.token_sample)
    return report.to_dict(), module.format_tokens(report)


def run(args: argparse.Namespace) -> int:
    root = Path(args.dir)
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise ConfigError(f"dir = {str(root)!r}: no meta/info.json; not a finished packlab dataset")
    info = read_info(root)  # typed, its format_version checked
    dists = collect(dataset_cases(root))
    tokens, tokens_text = sft_tokens(args)
    if args.json:
        as_json = json.loads(json.dumps(to_builtins(info), sort_keys=True))  # the file's key order
        summary = {"info": as_json, "distributions": {k: d.summary() for k, d in dists.items()}}
        if tokens_text:
            summary["sft_tokens"] = tokens if tokens is not None else {"note": tokens_text}
        print(json.dumps(summary, indent=1))
    else:
        print(format_report(info, dists))
        if tokens_text:
            print("\n" + tokens_text)
    if args.plots:
        for path in save_histograms(dists, args.plots):
            print(f"wrote {path}")
    return 0
