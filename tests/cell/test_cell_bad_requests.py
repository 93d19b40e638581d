"""Every kind of bad input gets a 4xx with one line naming the field and its value, and the
server goes on serving."""

from __future__ import annotations

import base64
import copy
import io
import json

import numpy as np
import pytest
from cell_scenes import FLOOR, HEIGHT, SESSION, STEP, WIDTH
from fastapi.testclient import TestClient
from PIL import Image

from packlab.cell import schema
from packlab.cell.app import create_app
from packlab.cell.images import encode_depth
from packlab.cell.limits import MAX_BODY_BYTES, MAX_IMAGE_PIXELS
from packlab.cell.sessions import LocalSessions


def image(depth: np.ndarray, encoding: str = "f32") -> dict:
    """The wire image of ``depth`` as it is (no NaN cleaning: the bad values must arrive)."""
    dtype = {"f32": "<f4", "u16": "<u2"}[encoding]
    data = base64.b64encode(np.asarray(depth).astype(dtype).tobytes()).decode()
    return {"encoding": encoding, "shape": list(depth.shape), "data": data}


def png8() -> str:
    buffer = io.BytesIO()
    Image.fromarray(np.full((HEIGHT, WIDTH), 100, dtype=np.uint8)).save(buffer, format="PNG")
    return base64.b64encode(buffer.getvalue()).decode()


def with_(base: dict, path: str, value) -> dict:
    """A copy of ``base`` with the dotted ``path`` set to ``value`` (``...`` deletes it)."""
    out = copy.deepcopy(base)
    *parents, last = path.split(".")
    node = out
    for key in parents:
        node = node[int(key)] if isinstance(node, list) else node[key]
    if value is ...:
        del node[last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return out


def nan_image() -> dict:
    depth = FLOOR.copy()
    depth[7, 9] = np.nan
    return image(depth)


def negative_image() -> dict:
    depth = FLOOR.copy()
    depth[3, 4] = -5.0
    return image(depth)


# (what is wrong, "session" or "step" request, the request, status, words the line must hold)
BAD_STEPS = [
    ("image shape is not the intrinsics'", with_(STEP, "container_image", image(FLOOR[:, :60])),
     422, "container_image.shape = [120, 60]: the camera's intrinsics say [height, width] = [120"),
    ("image data of the wrong length", with_(STEP, "container_image.shape", [120, 81]),
     422, "container_image.data = '38400 bytes': need 38880 bytes for shape [120, 81] of f32"),
    ("image with three axes", with_(STEP, "container_image.shape", [120, 80, 1]),
     422, "container_image.shape = "),
    ("unknown image dtype", with_(STEP, "container_image.encoding", "f64"),
     422, "container_image.encoding = 'f64'"),
    ("NaN depth", with_(STEP, "container_image", nan_image()),
     422, "container_image.data[7, 9] = nan: NaN or infinite; send 0 for a pixel without depth"),
    ("negative depth", with_(STEP, "container_image", negative_image()),
     422, "container_image.data[3, 4] = -5.0: negative depth"),
    ("depth beyond the limit", with_(STEP, "container_image", image(FLOOR * 1e3)),
     422, "container_image.data[0, 0] = 1900000.0: beyond 100000 mm"),
    ("an image over the pixel limit", with_(STEP, "container_image.shape", [4096, 2048]),
     422, f"container_image.shape = [4096, 2048]: more than {MAX_IMAGE_PIXELS} pixels"),
    ("malformed base64", with_(STEP, "container_image.data", "not*base64!"),
     422, "container_image.data = 'not*base64!': malformed base64"),
    ("an 8-bit PNG", with_(STEP, "container_image", {"encoding": "png16", "data": png8()}),
     422, "container_image.data = 'PNG mode L': need a 16-bit greyscale PNG"),
    ("a box larger than the container", with_(STEP, "detections.0.size_mm", [700, 500, 100]),
     422, "detections[0].size_mm = [700, 500, 100]: larger than the container 600 x 400 x 400"),
    ("a box taller than the container", with_(STEP, "detections.0.size_mm", [100, 100, 450]),
     422, "detections[0].size_mm = [100, 100, 450]: larger than the container"),
    ("an empty buffer", with_(STEP, "detections", []),
     422, "detections = 0: an empty list: the buffer must show at least one box"),
    ("more boxes than the buffer holds", with_(STEP, "detections", [{"size_mm": [100] * 3}] * 4),
     422, "detections = 4: more boxes than the session's buffer_size 3"),
    ("neither buffer image nor detections", with_(STEP, "detections", ...),
     422, "buffer_image, detections = 'neither': send exactly one of the two"),
    ("a buffer image without a buffer camera",
     with_(with_(STEP, "detections", ...), "buffer_image", encode_depth(FLOOR)),
     422, "buffer_camera = None: neither the session nor the step has one"),
    ("fewer remaining than shown",
     with_(with_(STEP, "remaining", 1), "detections", [{"size_mm": [100] * 3}] * 2),
     422, "remaining = 1: fewer than the 2 boxes in the buffer"),
    ("no box to come", with_(STEP, "remaining", 0),
     422, "remaining = 0: Input should be greater than or equal to 1"),
    ("a misspelt field", with_(STEP, "detection", []),
     422, "detection = []: Extra inputs are not permitted"),
]  # fmt: skip

BAD_SESSIONS = [
    ("missing calibration", with_(SESSION, "container_camera", ...),
     422, "container_camera: missing"),
    ("a scaled pose matrix",
     with_(SESSION, "container_camera.pose.matrix.0", [0, 2, 0, 0]),
     422, "container_camera.pose.matrix = [[0.0, 2.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]"),
    ("a pose that is not a 4 x 4 matrix",
     with_(SESSION, "container_camera.pose.matrix", [[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
     422, "container_camera.pose.matrix[0][3]: missing (and 3 more)"),
    ("a quaternion that is not unit",
     with_(SESSION, "container_camera.pose",
           {"translation_mm": [0, 0, 1900], "quaternion_wxyz": [0, 1, 1, 0]}),
     422, "container_camera.pose.quaternion_wxyz = [0.0, 1.0, 1.0, 0.0]: not a unit quaternion"),
    ("a pose given twice",
     with_(SESSION, "container_camera.pose.quaternion_wxyz", [1, 0, 0, 0]),
     422, "container_camera.pose = "),
    ("a negative focal length",
     with_(SESSION, "container_camera.intrinsics",
           {"model": "pinhole", "fx": -5, "fy": 500, "cx": 40, "cy": 60, "width": 80,
            "height": 120}),
     422, "container_camera.intrinsics.pinhole.fx = -5: Input should be greater than or equal"),
    ("an unknown camera model",
     with_(SESSION, "container_camera.intrinsics.model", "fisheye"),
     422, "container_camera.intrinsics = "),
    ("unknown policy", with_(SESSION, "policy", "plan-fastest"),
     422, "policy = 'plan-fastest': unknown; available: "),
    ("a policy that needs the case", with_(SESSION, "policy", "oracle"),
     422, "policy = 'oracle': replays a case's plan, which a cell has not"),
    ("an option the policy does not take", with_(SESSION, "policy_options", {"warp": 9}),
     422, "policy_options = {'warp': 9}: plan: unknown option 'warp'"),
    ("an unknown sensing preset", with_(SESSION, "sensing", {"preset": "lidar"}),
     422, "sensing.preset = 'lidar': Input should be"),
    ("a container with no cell", with_(SESSION, "container.size_mm", [20, 400, 400]),
     422, "container.size_mm = [20.0, 400.0, 400.0]: 0 x 16 cells of 25 mm"),
    ("a buffer size of zero", with_(SESSION, "buffer_size", 0),
     422, "buffer_size = 0: Input should be greater than or equal to 1"),
]  # fmt: skip


def assert_one_line(response, status: int, words: str) -> None:
    assert response.status_code == status, response.text
    line = response.json()["error"]
    assert "\n" not in line and len(line) < 1000, line
    assert words in line, line


def open_session(http) -> str:
    response = http.post("/v1/sessions", json=SESSION)
    assert response.status_code == 201, response.text
    return response.json()["session_id"]


@pytest.mark.parametrize(
    ("what", "body", "status", "words"), BAD_STEPS, ids=[b[0] for b in BAD_STEPS]
)
def test_a_bad_step_is_refused_in_one_line(http, what, body, status, words):
    session_id = open_session(http)
    assert_one_line(http.post(f"/v1/sessions/{session_id}/step", json=body), status, words)
    # The server goes on serving, the session too.
    good = http.post(f"/v1/sessions/{session_id}/step", json=STEP)
    assert good.status_code == 200, good.text


@pytest.mark.parametrize(
    ("what", "body", "status", "words"), BAD_SESSIONS, ids=[b[0] for b in BAD_SESSIONS]
)
def test_a_bad_session_is_refused_in_one_line(http, what, body, status, words):
    assert_one_line(http.post("/v1/sessions", json=body), status, words)
    assert_one_line(http.post("/v1/plan", json={**body, **STEP}), status, words)
    open_session(http)


def test_an_unknown_session_is_404(http):
    assert_one_line(http.post("/v1/sessions/nope/step", json=STEP), 404, "session = 'nope'")
    assert_one_line(http.delete("/v1/sessions/nope"), 404, "session = 'nope': unknown")


def test_malformed_json_is_400(http):
    response = http.post(
        "/v1/sessions", content=b'{"container": ', headers={"content-type": "application/json"}
    )
    assert_one_line(response, 400, "body: malformed JSON")


def test_nan_in_the_json_is_refused(http):
    text = json.dumps(with_(SESSION, "container_camera.intrinsics.pixel_mm", float("nan")))
    response = http.post("/v1/sessions", content=text, headers={"content-type": "application/json"})
    assert_one_line(response, 422, "container_camera.intrinsics.orthographic.pixel_mm = nan")


def test_a_body_over_the_limit_is_413_before_it_is_read(http):
    response = http.post(
        "/v1/plan",
        content=b"x" * 10,
        headers={"content-type": "application/json", "content-length": str(MAX_BODY_BYTES + 1)},
    )
    assert_one_line(response, 413, f"more than the {MAX_BODY_BYTES} bytes")
    assert http.get("/v1/health").status_code == 200


def test_a_body_sent_in_chunks_over_the_limit_is_413(sessions):
    app = create_app(sessions, "plan-fast", max_body_bytes=1000)
    with TestClient(app, raise_server_exceptions=False) as http:
        chunks = (b" " * 100 for _ in range(20))  # no Content-Length: sent chunked
        response = http.post(
            "/v1/plan", content=chunks, headers={"content-type": "application/json"}
        )
        assert_one_line(response, 413, "more than the 1000 bytes")
        assert http.get("/v1/health").status_code == 200


def test_a_full_server_is_503_and_a_closed_session_frees_a_place(http, sessions):
    sessions.max_sessions = 2
    first = open_session(http)
    open_session(http)
    assert_one_line(http.post("/v1/sessions", json=SESSION), 503, "2 open, the most")
    assert http.delete(f"/v1/sessions/{first}").status_code == 204
    open_session(http)


def test_an_idle_session_is_closed_when_the_next_opens():
    now = [0.0]
    sessions = LocalSessions("plan-fast", idle_s=10.0, clock=lambda: now[0])
    request = schema.SessionRequest.model_validate(SESSION)
    first = sessions.open(request).session_id
    now[0] = 11.0
    sessions.open(request)
    assert sessions.count() == 1
    with pytest.raises(KeyError):
        sessions.close(first)


def test_there_are_at_least_twelve_kinds():
    assert len(BAD_STEPS) + len(BAD_SESSIONS) >= 12
