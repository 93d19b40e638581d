"""Encoding an episode's contexts step after step with what repeats memoised (``EncodeMemo``, the
image processor's patch buffer) gives exactly the tensors of encoding each context afresh."""

from __future__ import annotations

import pytest
from _cases import small_case

from packlab.core.types import Action

FAMILIES = ("qwen3_5", "qwen3_vl", "qwen2_5_vl")


def _contexts(steps: int) -> list[list[dict]]:
    """The contexts a ``vlm`` policy encodes over the first ``steps`` steps of an episode."""
    from packlab.sim.episode import Episode
    from packlab.vlm.prompt.context import ContextRenderer

    renderer = ContextRenderer()
    episode = Episode("geometric")
    episode.reset(small_case(), 0)
    out = []
    for _ in range(steps):
        out.append(renderer.messages(episode.observe()))
        episode.step(Action(0, 0, 0, 0))
    return out


def _same(a, b, torch) -> bool:
    tensors = ("input_ids", "mm_token_type_ids", "pixel_values", "image_grid_thw")
    for name in tensors:
        x, y = getattr(a, name), getattr(b, name)
        if (x is None) != (y is None) or (x is not None and not torch.equal(x, y)):
            return False
    return True


@pytest.mark.torch
@pytest.mark.parametrize("family", FAMILIES)
def test_memoised_encoding_equals_fresh_encoding_step_after_step(torch, family):
    from packlab.vlm.data.encoding import EncodeMemo, encode
    from packlab.vlm.infer.generate import MemoImageProcessor
    from packlab.vlm.model.tiny import build_tiny_model
    from packlab.vlm.prompt.render import drop_oldest_step

    vlm = build_tiny_model(family, "tiny")
    contexts = _contexts(4)
    # a context that does not extend the previous one: its oldest step dropped, then the full one
    contexts += [drop_oldest_step(list(contexts[-1])), contexts[-1]]
    memo, processor = EncodeMemo(), MemoImageProcessor(vlm.image_processor)
    encoded = []
    for messages in contexts:
        fast = encode(messages, vlm.tokenizer, processor, memo=memo)
        plain = encode(messages, vlm.tokenizer, vlm.image_processor)
        assert _same(fast, plain, torch)
        encoded.append((fast, plain))
    # tensors handed out earlier are unchanged by the calls after them (the patch buffer only
    # appends, and a call that does not extend the previous one gets a buffer of its own)
    assert all(_same(fast, plain, torch) for fast, plain in encoded)
    assert memo._segmentwise is True  # the project's tokenizer splits at special tokens


@pytest.mark.torch
def test_memo_tokenises_the_whole_text_where_segments_would_differ(torch):
    from packlab.vlm.data.encoding import IMAGE_PAD, EncodeMemo

    class JoiningTokenizer:
        """Merges a pad with the character after it: segments cannot be tokenised alone."""

        def convert_tokens_to_ids(self, token):
            return 1

        def __call__(self, text, add_special_tokens=False):
            ids, i = [], 0
            while i < len(text):
                if text.startswith(IMAGE_PAD, i):
                    follows = text[i + len(IMAGE_PAD) : i + len(IMAGE_PAD) + 1]
                    ids.append(1 if follows in ("", "<") else 2)
                    i += len(IMAGE_PAD)
                else:
                    ids.append(ord(text[i]))
                    i += 1
            return {"input_ids": ids}

    tok = JoiningTokenizer()
    memo = EncodeMemo()
    parts, counts = ["ab", "cd", "e"], [2, 1]
    whole = tok("ab" + IMAGE_PAD * 2 + "cd" + IMAGE_PAD + "e")["input_ids"]
    assert memo.token_ids(parts, counts, tok) == whole
    assert memo._segmentwise is False
    assert memo.token_ids(parts, counts, tok) == whole


@pytest.mark.torch
def test_memo_recognises_an_image_by_identity_and_an_array_by_content(torch):
    import numpy as np
    from PIL import Image

    from packlab.vlm.data.encoding import EncodeMemo, ProcessingConfig

    memo, config = EncodeMemo(), ProcessingConfig()
    image = Image.new("RGB", (32, 32), (1, 2, 3))
    assert memo.image(image, config) is memo.image(image, config)
    array = np.zeros((32, 32, 3), dtype=np.uint8)
    first = memo.image(array, config)
    array[0, 0] = (255, 0, 0)  # changed in place: resolved again
    assert memo.image(array, config).getpixel((0, 0)) == (255, 0, 0) != first.getpixel((0, 0))


@pytest.mark.torch
@pytest.mark.parametrize("family", FAMILIES)
def test_positions_taken_from_the_previous_prompt_equal_the_whole_computation(torch, family):
    from packlab.vlm.infer.generate import PrefixCachedGenerator
    from packlab.vlm.model.tiny import build_tiny_model
    from packlab.vlm.prompt.render import drop_oldest_step

    gen = PrefixCachedGenerator(build_tiny_model(family, "tiny"), max_new_tokens=4)
    contexts = _contexts(4)
    contexts += [drop_oldest_step(list(contexts[-1])), contexts[-1]]
    whole_positions = gen._positions
    lengths: list[int] = []  # tokens each call computed positions for

    def spy(input_ids, mm, grid):
        lengths.append(int(input_ids.shape[0]))
        return whole_positions(input_ids, mm, grid)

    gen._positions = spy
    partial = 0
    for messages in contexts:
        lengths.clear()
        prompt = gen._encode(messages)
        partial += sum(lengths) < len(prompt.ids)
        enc = prompt.enc
        whole = whole_positions(enc.input_ids, enc.mm_token_type_ids, enc.image_grid_thw)
        assert torch.equal(prompt.positions, whole)
    # every context after the first shares a prefix with the one before it (the dropped step's
    # context only its system prompt, which ends before the first image)
    assert partial == len(contexts) - 1
