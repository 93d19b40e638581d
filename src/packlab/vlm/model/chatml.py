"""ChatML as the project's own tokenizer writes it: the special tokens and the chat template,
plus :func:`render_chat`, the same template rendered in plain Python.

The template (:data:`CHAT_TEMPLATE`) is saved with every checkpoint that carries the project's
tokenizer (``chat_template.jinja``); transformers renders it with jinja. The ONNX runtime plays
from the core install, which has neither transformers nor jinja, so it renders the template's
few rules here instead; it accepts a checkpoint only when the saved template is this one
(:func:`is_project_template`), and a test checks both renderings equal on many states.
Torch-free (the core install imports it).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

PAD_TOKEN = "<|endoftext|>"
IM_START, IM_END = "<|im_start|>", "<|im_end|>"
VISION_START, VISION_END = "<|vision_start|>", "<|vision_end|>"
IMAGE_PAD, VIDEO_PAD, VISION_PAD = "<|image_pad|>", "<|video_pad|>", "<|vision_pad|>"
#: What one image item of a message becomes; the processor (or :mod:`packlab.vlm.candidate`)
#: then repeats ``<|image_pad|>`` once per merged visual token.
IMAGE_TEXT = VISION_START + IMAGE_PAD + VISION_END

# ChatML as the Qwen models use it. Images become <|vision_start|><|image_pad|><|vision_end|>;
# the processor then repeats <|image_pad|> once per merged visual token. The pieces are shared by
# the inference template and its training version below.
_TURN_START = "{%- for message in messages -%}{{- '<|im_start|>' + message['role'] + '\\n' -}}"
_CONTENT = (
    "{%- if message['content'] is string -%}{{- message['content'] -}}"
    "{%- else -%}{%- for item in message['content'] -%}"
    "{%- if item['type'] == 'image' -%}{{- '<|vision_start|><|image_pad|><|vision_end|>' -}}"
    "{%- elif item['type'] == 'text' -%}{{- item['text'] -}}{%- endif -%}"
    "{%- endfor -%}{%- endif -%}"
)
_GENERATION_PROMPT = (
    "{%- endfor -%}{%- if add_generation_prompt -%}{{- '<|im_start|>assistant\\n' -}}{%- endif -%}"
)
CHAT_TEMPLATE = _TURN_START + _CONTENT + "{{- '<|im_end|>\\n' -}}" + _GENERATION_PROMPT


#: :data:`CHAT_TEMPLATE` with ``{% generation %}`` markers around each assistant turn's text and
#: its ``<|im_end|>``: it renders the same string, and transformers' processors return from it the
#: mask of assistant tokens that TRL's assistant-only loss reads (the end-of-turn token inside the
#: mask, so the model learns to stop).
TRAINING_CHAT_TEMPLATE = (
    _TURN_START
    + "{%- if message['role'] == 'assistant' -%}{%- generation -%}"
    + _CONTENT
    + "{{- '<|im_end|>' -}}{%- endgeneration -%}{{- '\\n' -}}"
    + "{%- else -%}"
    + _CONTENT
    + "{{- '<|im_end|>\\n' -}}"
    + "{%- endif -%}"
    + _GENERATION_PROMPT
)


def is_project_template(template: str) -> bool:
    """Whether a saved chat template is :data:`CHAT_TEMPLATE` or its training version (which a
    trainer's checkpoint carries; it renders the same), a trailing newline aside."""
    return template.strip() in (CHAT_TEMPLATE, TRAINING_CHAT_TEMPLATE)


def _content_text(content: str | Sequence[dict[str, Any]]) -> str:
    if isinstance(content, str):
        return content
    parts = []
    for item in content:
        if item["type"] == "image":
            parts.append(IMAGE_TEXT)
        elif item["type"] == "text":
            parts.append(item["text"])  # other item types write nothing, as in the template
    return "".join(parts)


def render_chat(messages: Sequence[dict[str, Any]], add_generation_prompt: bool = True) -> str:
    """:data:`CHAT_TEMPLATE` rendered without jinja: each message as
    ``<|im_start|>role\\n content <|im_end|>\\n``, then the assistant header if asked."""
    turns = [f"{IM_START}{m['role']}\n{_content_text(m['content'])}{IM_END}\n" for m in messages]
    return "".join(turns) + (f"{IM_START}assistant\n" if add_generation_prompt else "")
