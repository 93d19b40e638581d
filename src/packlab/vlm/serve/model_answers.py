"""Answers of a local model for the test server (vlm extra): OpenAI messages -> the chat
messages of :mod:`packlab.vlm.prompt.render` -> the same greedy, prefix-cached generator as the
``vlm`` policy."""

from __future__ import annotations

import threading
from typing import Any

from jinja2 import TemplateError

from packlab.vlm.data.encoding import ProcessingConfig
from packlab.vlm.infer.generate import PrefixCachedGenerator
from packlab.vlm.model.spec import make_model
from packlab.vlm.serve.openai_messages import from_openai_messages
from packlab.vlm.serve.protocol import AnswerFn, Reply, RequestError, requested_max_tokens


def model_answer_fn(
    model: str | Any = "tiny:qwen3_5:tiny",
    max_new_tokens: int = 64,
    reuse_prefix: bool = True,
    **processing: Any,
) -> AnswerFn:
    """Answer with a local model (a ``VLM``, a checkpoint directory or ``tiny:F:S``), greedy.

    ``max_completion_tokens`` / ``max_tokens`` in a request cap the answer length. Requests are
    served one at a time. Messages the model cannot take (an image that does not decode, an
    order of roles the chat template refuses) raise RequestError (400).
    """
    vlm = make_model(model) if isinstance(model, str) else model
    generator = PrefixCachedGenerator(
        vlm, ProcessingConfig(**processing), max_new_tokens, reuse_prefix
    )
    lock = threading.Lock()

    def answer(request: dict[str, Any]) -> Reply:
        messages = from_openai_messages(request["messages"])
        with lock:
            generator.max_new_tokens = requested_max_tokens(request, max_new_tokens)
            try:
                gen = generator.generate(messages)
            except TemplateError as e:
                raise RequestError(
                    f"the chat template refused the messages: {e.message}", "messages"
                ) from None
            except ValueError as e:  # the encoder's input checks, e.g. longer than max_length
                raise RequestError(
                    f"the model cannot take these messages: {e}", "messages"
                ) from None
        return Reply(
            content=gen.text,
            usage={"prompt_tokens": gen.prompt_tokens, "completion_tokens": len(gen.token_ids)},
            finish_reason="stop" if gen.finished else "length",
        )

    return answer
