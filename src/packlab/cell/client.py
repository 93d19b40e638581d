"""A Python client of the cell service (httpx): open a session, step with numpy depth images or
detections, get typed answers back, close.

    with CellClient("http://127.0.0.1:8100") as client:
        session = client.open(request)                     # a schema.SessionRequest
        answer = client.step(session.session_id, container_depth, buffer_depth=buffer_depth)
        client.close(session.session_id)

Depth arrays are in mm, (height, width); NaN, 0 or negative pixels are sent as missing (0).
A refusal raises :class:`CellServiceError` with the server's one-line reason.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Self, TypeVar

import httpx
import numpy as np
from pydantic import BaseModel

from packlab.cell import schema
from packlab.cell.images import Encoding, encode_depth
from packlab.core.errors import PacklabError

_M = TypeVar("_M", bound=BaseModel)


class CellServiceError(PacklabError):
    """The service refused a request (4xx) or failed (5xx): its status and one-line reason."""

    def __init__(self, status: int, reason: str):
        super().__init__(f"cell service answered {status}: {reason}")
        self.status, self.reason = status, reason


def depth_image(depth_mm: np.ndarray, encoding: Encoding = "f32") -> schema.DepthImage:
    """A depth array in mm as the request's image (NaN, 0, negative: missing)."""
    return schema.DepthImage.model_validate(encode_depth(depth_mm, encoding))


class CellClient:
    """The service at ``base_url`` (``http://HOST:PORT``), answers awaited up to ``timeout_s``.
    ``client`` replaces the connection: any ``httpx.Client`` with its base URL set (FastAPI's
    ``TestClient`` over the app in tests)."""

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8100",
        timeout_s: float = 60.0,
        client: httpx.Client | None = None,
    ):
        self._http = client or httpx.Client(base_url=base_url, timeout=timeout_s)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self._http.close()

    def health(self) -> schema.Health:
        return self._call("GET", "/v1/health", schema.Health)

    def policies(self) -> schema.PolicyList:
        return self._call("GET", "/v1/policies", schema.PolicyList)

    def open(self, request: schema.SessionRequest) -> schema.SessionOpened:
        """Open a session for one container."""
        return self._call("POST", "/v1/sessions", schema.SessionOpened, request)

    def step(
        self,
        session_id: str,
        container_depth: np.ndarray,
        buffer_depth: np.ndarray | None = None,
        detections: Sequence[schema.Detection] | None = None,
        remaining: int | None = None,
        encoding: Encoding = "f32",
        container_camera: schema.Camera | None = None,
        buffer_camera: schema.Camera | None = None,
    ) -> schema.StepAnswer:
        """The next placement: the container image and the buffer image or detections; a
        camera given here replaces the session's for this step (one that moved)."""
        request = step_request(container_depth, buffer_depth, detections, remaining, encoding)
        request.container_camera, request.buffer_camera = container_camera, buffer_camera
        return self._call("POST", f"/v1/sessions/{session_id}/step", schema.StepAnswer, request)

    def plan(
        self,
        session: schema.SessionRequest,
        container_depth: np.ndarray,
        buffer_depth: np.ndarray | None = None,
        detections: Sequence[schema.Detection] | None = None,
        remaining: int | None = None,
        encoding: Encoding = "f32",
    ) -> schema.StepAnswer:
        """One placement with no session kept (a one-step session)."""
        step = step_request(container_depth, buffer_depth, detections, remaining, encoding)
        request = schema.PlanRequest.model_validate(
            {**session.model_dump(exclude_unset=True), **step.model_dump(exclude_none=True)}
        )
        return self._call("POST", "/v1/plan", schema.StepAnswer, request)

    def close(self, session_id: str) -> None:
        self._send("DELETE", f"/v1/sessions/{session_id}")

    def _call(self, method: str, path: str, answer: type[_M], body: BaseModel | None = None) -> _M:
        return answer.model_validate(self._send(method, path, body).json())

    def _send(self, method: str, path: str, body: BaseModel | None = None) -> httpx.Response:
        content = None if body is None else body.model_dump_json(exclude_none=True)
        headers = {"content-type": "application/json"} if content is not None else None
        response = self._http.request(method, path, content=content, headers=headers)
        if response.status_code >= 400:
            raise CellServiceError(response.status_code, _reason(response))
        return response


def step_request(
    container_depth: np.ndarray,
    buffer_depth: np.ndarray | None = None,
    detections: Sequence[schema.Detection] | None = None,
    remaining: int | None = None,
    encoding: Encoding = "f32",
) -> schema.StepRequest:
    """A step's request from numpy depth images (mm) and/or detections."""
    return schema.StepRequest(
        container_image=depth_image(container_depth, encoding),
        buffer_image=None if buffer_depth is None else depth_image(buffer_depth, encoding),
        detections=None if detections is None else list(detections),
        remaining=remaining,
    )


def _reason(response: httpx.Response) -> str:
    try:
        body: Any = response.json()
    except ValueError:
        return response.text[:200]
    return str(body.get("error", body)) if isinstance(body, dict) else str(body)[:200]


__all__ = ["CellClient", "CellServiceError", "depth_image", "step_request"]
