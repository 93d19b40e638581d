"""What marks a candidate-mode checkpoint directory (torch-free, for dispatch without torch)."""

from __future__ import annotations

from pathlib import Path

HEAD_FILE = "pointer_head.safetensors"
CANDIDATE_FORMAT = "candidate"


def is_pointer_dir(path: str | Path) -> bool:
    return (Path(path) / HEAD_FILE).is_file()
