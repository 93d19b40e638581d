"""The cell service's HTTP API (FastAPI): sessions, steps, a stateless plan, health, policies.

Every refusal is a 4xx whose body is ``{"error": "<field> = <value>: <what is wrong>"}`` on one
line, and the server goes on serving. The planning runs in the server's thread pool, or in
planner processes (``packlab.cell.workers``), never on the event loop.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from fastapi import FastAPI, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

import packlab
from packlab.cell import schema
from packlab.cell.errors import CellInputError, ServiceFull, UnknownSession, short_value
from packlab.cell.limits import MAX_BODY_BYTES
from packlab.cell.sessions import SessionBackend
from packlab.policies.registry import available_policies

log = logging.getLogger("packlab.cell")

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]

#: The error answers every route may give, for the OpenAPI schema.
ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": schema.ErrorAnswer, "description": text}
    for code, text in (
        (400, "malformed JSON"),
        (404, "unknown session"),
        (413, "request body over the limit"),
        (422, "a field's value cannot be used: the line names it"),
        (503, "the server keeps as many sessions as it may, or lost a planner"),
    )
}


class _TooLarge(Exception):
    pass


#: The scope key ``BodyLimit`` sets when a body sent in chunks passed the limit.
TOO_LARGE = "packlab.cell.body_too_large"


class BodyLimit:
    """Answer 413 to a request body over ``max_bytes``, before it is read into memory (by its
    Content-Length) or as soon as it passes the limit (a body sent in chunks)."""

    def __init__(self, app: Callable[[Scope, Receive, Send], Awaitable[None]], max_bytes: int):
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = dict(scope.get("headers") or []).get(b"content-length", b"0")
        if not length.isdigit() or int(length) > self.max_bytes:
            await self._refuse(scope, receive, send, length.decode("latin-1"))
            return
        received = 0

        async def limited() -> Message:
            nonlocal received
            message = await receive()
            received += len(message.get("body", b""))
            if received > self.max_bytes:
                # FastAPI turns an error while it reads the body into a 400; this flag lets
                # the handler answer 413 instead.
                scope[TOO_LARGE] = True
                raise _TooLarge
            return message

        try:
            await self.app(scope, limited, send)
        except _TooLarge:
            await self._refuse(scope, receive, send, f"over {self.max_bytes}")

    async def _refuse(self, scope: Scope, receive: Receive, send: Send, length: str) -> None:
        line = f"body = {length} bytes: more than the {self.max_bytes} bytes a request may have"
        await JSONResponse({"error": line}, status_code=413)(scope, receive, send)


def create_app(
    backend: SessionBackend, default_policy: str, max_body_bytes: int = MAX_BODY_BYTES
) -> FastAPI:
    """The service over ``backend``'s sessions; ``default_policy`` serves sessions naming none,
    and a request body may have up to ``max_body_bytes``."""
    app = FastAPI(
        title="packlab cell service",
        version=packlab.__version__,
        summary="Depth images in, a placement out: packlab's perception and policies for a "
        "robot packing cell.",
    )
    app.add_middleware(BodyLimit, max_bytes=max_body_bytes)
    _add_error_handlers(app, max_body_bytes)
    _add_routes(app, backend, default_policy)
    return app


def _add_routes(app: FastAPI, backend: SessionBackend, default_policy: str) -> None:
    # Plain (not async) functions: FastAPI runs them in its thread pool, off the event loop.
    @app.post("/v1/sessions", status_code=201, responses=ERRORS)
    def open_session(request: schema.SessionRequest) -> schema.SessionOpened:
        """Open a session for one container; its steps keep the history the policy reads."""
        return backend.open(request)

    @app.post("/v1/sessions/{session_id}/step", responses=ERRORS)
    def step(session_id: str, request: schema.StepRequest) -> schema.StepAnswer:
        """Plan the next placement from the cameras' images (or the cell's detections)."""
        return backend.step(session_id, request)

    @app.delete("/v1/sessions/{session_id}", status_code=204, responses=ERRORS)
    def close_session(session_id: str) -> Response:
        """Close a session (its container is done)."""
        backend.close(session_id)
        return Response(status_code=204)

    @app.post("/v1/plan", responses=ERRORS)
    def plan(request: schema.PlanRequest) -> schema.StepAnswer:
        """One placement from one request, no session kept: a one-step session."""
        return backend.plan(request)

    @app.get("/v1/health")
    def health() -> schema.Health:
        return schema.Health(
            status="ok",
            version=packlab.__version__,
            sessions=backend.count(),
            workers=backend.workers,
        )

    @app.get("/v1/policies")
    def policies() -> schema.PolicyList:
        """The policies a session may name; ``default`` serves sessions that name none."""
        return schema.PolicyList(default=default_policy, policies=available_policies())


def _add_error_handlers(app: FastAPI, max_body_bytes: int) -> None:
    async def known(request: Request, exc: Exception) -> JSONResponse:
        status = getattr(exc, "status", 422)
        return JSONResponse({"error": str(exc)}, status_code=status)

    for error in (CellInputError, UnknownSession, ServiceFull):
        app.add_exception_handler(error, known)

    async def invalid(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        errors = exc.errors()
        status = 400 if errors and errors[0].get("type") == "json_invalid" else 422
        return JSONResponse({"error": validation_line(errors)}, status_code=status)

    async def http(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, StarletteHTTPException)
        if request.scope.get(TOO_LARGE):
            line = f"body: more than the {max_body_bytes} bytes a request may have"
            return JSONResponse({"error": line}, status_code=413)
        return JSONResponse(
            {"error": f"{request.method} {request.url.path}: {exc.detail}"},
            status_code=exc.status_code,
        )

    async def internal(request: Request, exc: Exception) -> JSONResponse:
        log.exception("cell service: %s %s failed", request.method, request.url.path)
        line = f"internal error ({type(exc).__name__}: {short_value(str(exc))})"
        return JSONResponse({"error": line}, status_code=500)

    app.add_exception_handler(RequestValidationError, invalid)
    app.add_exception_handler(StarletteHTTPException, http)
    app.add_exception_handler(Exception, internal)


def validation_line(errors: Any) -> str:
    """One line from pydantic's errors: the first one's field, value and message, and how many
    more there are."""
    if not errors:
        return "body: invalid request"
    first = errors[0]
    loc = [part for part in first.get("loc", ()) if part != "body"]
    field = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in loc).lstrip(".")
    message = str(first.get("msg", "invalid")).removeprefix("Value error, ")
    if first.get("type") == "json_invalid":
        line = f"body: malformed JSON ({first.get('ctx', {}).get('error', message)})"
    elif first.get("type") == "missing":
        line = f"{field or 'body'}: missing"
    else:
        line = f"{field or 'body'} = {short_value(first.get('input'))}: {message}"
    more = len(errors) - 1
    return line + (f" (and {more} more)" if more else "")


__all__ = ["ERRORS", "BodyLimit", "create_app", "validation_line"]
