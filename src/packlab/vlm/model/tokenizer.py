"""The project's own tokenizer for tiny models: byte-level BPE trained offline on packing text.

Real checkpoints bring their own tokenizer; tiny random-weight models (tests, CPU runs) need one
that exists without any download. This one is trained with the ``tokenizers`` library on a
corpus rendered by :mod:`packlab.vlm.prompt.render` itself, so the prompt's phrases become few
tokens (short sequences keep CPU training cheap), while the byte-level alphabet still encodes any
text. Normalisation and pre-tokenisation are the Qwen3.5 tokenizer's (NFC, its split regex, which
puts every digit in its own token, then byte-level), so coordinates are spelled digit by digit as
in the real models, and transformers' Qwen3_5Tokenizer, which rebuilds that pipeline around a
saved vocabulary, tokenizes exactly as this one does. It carries the ChatML special tokens and
the Qwen vision tokens that the Qwen-VL models and :mod:`packlab.vlm.data.encoding` expect, and a
ChatML chat template (:mod:`.chatml`, torch-free).

Imports ``tokenizers``/``transformers``: only the vlm extra may import this module.
"""

from __future__ import annotations

import numpy as np
from tokenizers import Regex, Tokenizer, decoders, models, normalizers, pre_tokenizers, trainers
from transformers import PreTrainedTokenizerFast

from packlab.core.types import Action, Container, ShownItem
from packlab.vlm.model.chatml import (
    CHAT_TEMPLATE,
    IM_END,
    IM_START,
    IMAGE_PAD,
    PAD_TOKEN,
    VIDEO_PAD,
    VISION_END,
    VISION_PAD,
    VISION_START,
)
from packlab.vlm.prompt.render import PromptOptions, TurnState, action_text, render_messages

#: Special tokens in id order right after the byte alphabet; never split, skipped on decode.
SPECIAL_TOKENS: tuple[str, ...] = (
    PAD_TOKEN,
    IM_START,
    IM_END,
    VISION_START,
    VISION_END,
    VISION_PAD,
    IMAGE_PAD,
    VIDEO_PAD,
)
#: Added but not special (kept on decode): the reasoning tags the parser knows how to skip.
THINK_TOKENS: tuple[str, ...] = ("<think>", "</think>")
#: Marker written in packlab_model.json for checkpoints that carry this tokenizer.
TOKENIZER_NAME = "packlab-bpe-v1"

# Qwen3.5's pre-tokenisation regex (a format fact of that tokenizer; see module docstring).
_QWEN_SPLIT = (
    r"(?i:'s|'t|'re|'ve|'m|'ll|'d)|[^\r\n\p{L}\p{N}]?[\p{L}\p{M}]+|\p{N}"
    r"| ?[^\s\p{L}\p{M}\p{N}]+[\r\n]*|\s*[\r\n]+|\s+(?!\S)|\s+"
)


def packing_corpus(n_states: int = 200, seed: int = 0) -> list[str]:
    """Chat-formatted text of random packing states, rendered by the real prompt code."""
    rng = np.random.default_rng(seed)
    texts: list[str] = []
    for _ in range(n_states):
        nx, ny = (int(v) for v in rng.integers(4, 25, size=2))
        container = Container((nx * 25, ny * 25, int(rng.integers(50, 400)) * 2))
        k = int(rng.integers(1, 6))
        shown = tuple(
            ShownItem(i, i, (0, 0, 0), tuple(int(v) for v in rng.integers(1, 12, size=3)))  # type: ignore[arg-type]
            for i in range(k)
        )
        turn = TurnState(None, shown, int(rng.integers(0, 60)), int(rng.integers(k, 80)))
        act = Action(
            int(rng.integers(0, k)),
            int(rng.integers(0, 2)),
            int(rng.integers(0, nx)),
            int(rng.integers(0, ny)),
        )
        for msg in render_messages(container, [(turn, act)], turn, PromptOptions()):
            texts.extend(c["text"] for c in msg["content"] if c["type"] == "text")
        texts.append(action_text(act))
    texts.extend(["system\n", "user\n", "assistant\n"] * n_states)  # the ChatML role headers
    return texts


def build_tokenizer(vocab_size: int = 1024, seed: int = 0) -> PreTrainedTokenizerFast:
    """Train the byte-level BPE and wrap it for transformers (deterministic for a seed)."""
    tok = Tokenizer(models.BPE())
    tok.normalizer = normalizers.NFC()
    tok.pre_tokenizer = pre_tokenizers.Sequence(
        [
            pre_tokenizers.Split(Regex(_QWEN_SPLIT), behavior="isolated", invert=False),
            pre_tokenizers.ByteLevel(add_prefix_space=False, use_regex=False),
        ]
    )
    tok.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(
        vocab_size=vocab_size,
        special_tokens=list(SPECIAL_TOKENS),
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
        show_progress=False,
    )
    tok.train_from_iterator(packing_corpus(seed=seed), trainer=trainer)
    fast = PreTrainedTokenizerFast(
        tokenizer_object=tok,
        bos_token=None,
        eos_token=IM_END,
        pad_token=PAD_TOKEN,
        additional_special_tokens=[t for t in SPECIAL_TOKENS if t not in (PAD_TOKEN, IM_END)],
    )
    fast.add_tokens(list(THINK_TOKENS))
    fast.chat_template = CHAT_TEMPLATE
    return fast


def special_token_ids(tokenizer) -> dict[str, int]:
    """Ids the model config needs; raises KeyError naming a token the tokenizer lacks."""
    out: dict[str, int] = {}
    for name, token in (
        ("image_token_id", IMAGE_PAD),
        ("video_token_id", VIDEO_PAD),
        ("vision_start_token_id", VISION_START),
        ("vision_end_token_id", VISION_END),
        ("pad_token_id", PAD_TOKEN),
        ("eos_token_id", IM_END),
    ):
        tid = tokenizer.convert_tokens_to_ids(token)
        if tid is None or tid == tokenizer.unk_token_id:
            raise KeyError(f"tokenizer has no {token}")
        out[name] = int(tid)
    return out
