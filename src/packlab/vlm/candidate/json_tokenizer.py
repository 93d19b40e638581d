"""A checkpoint's ``tokenizer.json`` read with the ``tokenizers`` library alone (core install),
behind the few calls of the transformers tokenizer that :mod:`.encoding` makes, so the ONNX
runtime encodes a state with the very code the torch path uses.

The chat template is rendered by :func:`packlab.vlm.model.chatml.render_chat` (no jinja), so a
checkpoint is accepted only when its saved template is the project's own; a model trained from a
pretrained checkpoint with another template plays with ``runtime=torch``. Torch-free.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tokenizers import Tokenizer

from packlab.core.errors import ConfigError
from packlab.vlm.model.chatml import PAD_TOKEN, is_project_template, render_chat

TOKENIZER_FILE = "tokenizer.json"
TEMPLATE_FILE = "chat_template.jinja"


def saved_template(directory: Path) -> str | None:
    """The chat template saved in a checkpoint directory (its own file, else the tokenizer
    config's field), or None."""
    path = directory / TEMPLATE_FILE
    if path.is_file():
        return path.read_text()
    config = directory / "tokenizer_config.json"
    if config.is_file():
        template = json.loads(config.read_text()).get("chat_template")
        return template if isinstance(template, str) else None
    return None


class JsonTokenizer:
    """The transformers-tokenizer calls :mod:`.encoding` makes, on ``tokenizers`` alone."""

    def __init__(self, directory: str | Path) -> None:
        directory = Path(directory)
        path = directory / TOKENIZER_FILE
        if not path.is_file():
            raise ConfigError(f"{path}: no tokenizer (expected a checkpoint directory)")
        template = saved_template(directory)
        if template is None or not is_project_template(template):
            raise ConfigError(
                f"{directory}: its chat template is not packlab's own ChatML template, which "
                f"the ONNX runtime renders without jinja; play it with runtime=torch"
            )
        self._tokenizer = Tokenizer.from_file(str(path))
        self.pad_token_id = self._tokenizer.token_to_id(PAD_TOKEN)

    def __call__(
        self, text: str, add_special_tokens: bool = False, return_offsets_mapping: bool = False
    ) -> dict[str, list[Any]]:
        enc = self._tokenizer.encode(text, add_special_tokens=add_special_tokens)
        out: dict[str, list[Any]] = {"input_ids": list(enc.ids)}
        if return_offsets_mapping:
            out["offset_mapping"] = list(enc.offsets)
        return out

    def convert_tokens_to_ids(self, token: str) -> int:
        tid = self._tokenizer.token_to_id(token)
        if tid is None:
            raise ConfigError(f"the tokenizer has no token {token!r}")
        return int(tid)

    def apply_chat_template(
        self,
        messages: Sequence[dict[str, Any]],
        tokenize: bool = False,
        add_generation_prompt: bool = True,
    ) -> str:
        if tokenize:
            raise ValueError("JsonTokenizer renders text only (tokenize=False)")
        return render_chat(messages, add_generation_prompt)
