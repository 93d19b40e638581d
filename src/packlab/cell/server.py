"""Running the cell service: the sessions' home (this process or planner processes), uvicorn,
and the OpenAPI document."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import uvicorn
from fastapi import FastAPI

from packlab.cell.app import create_app
from packlab.cell.sessions import LocalSessions, SessionBackend
from packlab.cell.settings import DEFAULT_POLICY, ServeSettings
from packlab.cell.workers import ProcessSessions
from packlab.policies.registry import policy_factory


def make_backend(settings: ServeSettings) -> SessionBackend:
    """Where sessions live: this process for one worker, else ``workers`` planner processes."""
    if settings.workers > 1:
        return ProcessSessions(
            settings.workers, settings.policy, settings.max_sessions, settings.idle_s
        )
    return LocalSessions(settings.policy, settings.max_sessions, settings.idle_s)


def serve(settings: ServeSettings) -> None:
    """Serve until stopped (Ctrl-C, SIGTERM); the default policy must exist before it starts."""
    policy_factory(settings.policy)  # a misspelt --policy fails now, not at the first step
    backend = make_backend(settings)
    print(
        f"packlab cell: {settings.policy} at http://{settings.host}:{settings.port}/v1 "
        f"({settings.workers} planner process(es)); Ctrl-C stops",
        file=sys.stderr,
    )
    try:
        uvicorn.run(
            create_app(backend, settings.policy),
            host=settings.host,
            port=settings.port,
        )
    finally:
        backend.shutdown()


def openapi_document() -> dict[str, Any]:
    """The service's OpenAPI document, as the running server publishes it at /openapi.json."""
    app: FastAPI = create_app(LocalSessions(DEFAULT_POLICY), DEFAULT_POLICY)
    return app.openapi()


def write_openapi(path: Path | None) -> str:
    """The OpenAPI document as JSON text, written to ``path`` when given."""
    text = json.dumps(openapi_document(), indent=2) + "\n"
    if path is not None:
        path.write_text(text, encoding="utf-8")
    return text


__all__ = [
    "make_backend",
    "openapi_document",
    "serve",
    "write_openapi",
]
