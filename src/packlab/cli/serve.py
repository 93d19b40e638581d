"""``packlab serve``: a local OpenAI-compatible chat-completions server of a packing VLM (tests
and trials; needs the vlm extra). The ``endpoint`` policy can then be pointed at it."""

from __future__ import annotations

import argparse

from packlab.vlm.serve import command  # no torch at import


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Serve a checkpoint (or a tiny random model) at http://HOST:PORT/v1 under "
        "--served-name (default: the checkpoint directory's name) for the endpoint policy "
        "(packlab bench --policies endpoint with base_url=http://HOST:PORT/v1) or any OpenAI "
        "client. Streams with stream=true; a malformed request gets 400 and a reason."
    )
    command.add_arguments(p)
    p.set_defaults(func=command.run_server)
