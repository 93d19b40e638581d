"""``packlab serve``: a local OpenAI-compatible chat-completions server of a packing VLM (tests
and trials; needs the vlm extra). The ``endpoint`` policy can then be pointed at it."""

from __future__ import annotations

import argparse

from packlab.vlm.serve.command import add_arguments, run_server  # no torch at import


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "serve",
        help="serve a packing VLM over an OpenAI-compatible API (test server)",
        description="Serve a checkpoint (or a tiny random model) at http://HOST:PORT/v1 under "
        "--served-name (default: the checkpoint directory's name) for the endpoint policy "
        "(packlab bench --policies endpoint with base_url=http://HOST:PORT/v1) or any OpenAI "
        "client. Streams with stream=true; a malformed request gets 400 and a reason.",
    )
    add_arguments(p)
    p.set_defaults(func=run_server)
