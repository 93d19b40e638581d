"""What the cell service's tests send and compare with: steps rendered by packlab's simulated
cameras from generated cases (the data engine's ``train`` seed space; never a bench suite),
plan-fast's picks in this process, small valid requests as JSON, a ray-cast pinhole camera."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np

from packlab.cell.images import encode_depth
from packlab.cell.simulated import simulated_camera
from packlab.core.feasibility import footprint_fits
from packlab.core.types import Action, Case, HistoryEntry, Observation, ShownItem
from packlab.datagen import generate_cases
from packlab.policies import make_policy
from packlab.sim.buffer import size_cells
from packlab.sim.sensing import render_depth, sensor_preset
from packlab.sim.sensing.perception import heightmap_from_depth

#: The sensor preset of the tests' sessions: the robot path's default.
PRESET = "structured-light"


def generated_case(difficulty: str = "medium", seed: int = 5, slot: int = 0) -> Case:
    return generate_cases(difficulty, 1, seed, validate=False, domain="train", start=slot)[0]


# -- what plan-fast picks in this process ------------------------------------------------------


def in_process(case: Case, steps, preset: str = PRESET, sizes=None):
    """(action, heightmap, shown) per step as plan-fast decides them in this process."""
    container = case.container
    sensor = sensor_preset(preset)
    policy = make_policy("plan-fast")
    policy.reset(Case("reference", container, case.buffer_size, ()), 0)
    history, next_id, out = [], 0, []
    for t, scene in enumerate(steps):
        heightmap = heightmap_from_depth(
            scene.container_image, container, flat_tolerance_mm=sensor.flat_tolerance_mm
        )
        measured = sizes[t] if sizes else [e.size_mm for e in scene.buffer.found]
        shown = tuple(
            ShownItem(i, f"seen-{next_id + i:05d}", size, size_cells(size, container))
            for i, size in enumerate(measured)
        )
        next_id += len(shown)
        observation = Observation(t, container, heightmap, shown, tuple(history), scene.remaining)
        action = policy.act(observation)
        valid = not action.sets_aside and footprint_fits(
            heightmap.shape, action.x, action.y, *_footprint(shown[action.object_id], action)
        )
        history.append(HistoryEntry(heightmap, shown, action, valid))
        out.append((action, heightmap, shown))
    return out


def _footprint(item: ShownItem, action: Action) -> tuple[int, int]:
    l, w, _ = item.size_cells
    return (w, l) if action.rotation == 1 else (l, w)


# -- a small valid request, as JSON -------------------------------------------------------------

HEIGHT, WIDTH = 120, 80  # a 600 x 400 mm container at 5 mm pixels
CAMERA = {
    "intrinsics": {
        "model": "orthographic",
        "pixel_mm": 5.0,
        "width": WIDTH,
        "height": HEIGHT,
        "cx": -0.5,
        "cy": -0.5,
    },
    "pose": {"matrix": [[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 1900], [0, 0, 0, 1]]},
}
SESSION = {"container": {"size_mm": [600, 400, 400]}, "buffer_size": 3, "container_camera": CAMERA}
FLOOR = np.full((HEIGHT, WIDTH), 1900.0)  # an empty container seen from 1.9 m above its floor
STEP = {"container_image": encode_depth(FLOOR), "detections": [{"size_mm": [200, 150, 100]}]}
#: Two boxes apart on a 400 x 300 mm table seen from 1.5 m at 2 mm pixels, and the session
#: whose buffer camera that is.
TABLE = render_depth(
    np.array([[200.0, 150.0, 100.0], [150.0, 100.0, 50.0]]),
    np.array([[120.0, 100.0, 50.0], [300.0, 200.0, 25.0]]),
    np.array([[1.0, 0.0, 0.0, 0.0], [np.cos(0.2), 0.0, 0.0, np.sin(0.2)]]),
    (0.0, 0.0, 400.0, 300.0),
    2.0,
    1500.0,
)
#: The same container seen by a pinhole camera 1.9 m above its middle, looking straight down
#: with packlab's axes (a half turn about the diagonal between x and y: geometry.TOP_DOWN).
PINHOLE_SESSION = {
    **SESSION,
    "container_camera": {
        "intrinsics": {
            "model": "pinhole",
            "fx": 400.0,
            "fy": 400.0,
            "cx": (WIDTH - 1) / 2,
            "cy": (HEIGHT - 1) / 2,
            "width": WIDTH,
            "height": HEIGHT,
        },
        "pose": {
            "translation_mm": [300.0, 200.0, 1900.0],
            "quaternion_wxyz": [0.0, 0.5**0.5, 0.5**0.5, 0.0],
        },
    },
}
BUFFER_SESSION = {**SESSION, "buffer_camera": simulated_camera(TABLE).model_dump(exclude_none=True)}
BUFFER_STEP = {"container_image": encode_depth(FLOOR), "buffer_image": encode_depth(TABLE.depth_mm)}


# -- a pinhole camera, ray-cast ---------------------------------------------------------------


def look_at(camera_mm, target_mm, roll_deg: float = 0.0) -> np.ndarray:
    """The camera-to-frame rotation of a camera at ``camera_mm`` looking at ``target_mm``,
    turned ``roll_deg`` about its optical axis (columns: the camera's x, y, z in the frame)."""
    z = np.asarray(target_mm, float) - np.asarray(camera_mm, float)
    z /= np.linalg.norm(z)
    y = np.cross(z, [1.0, 0.0, 0.0])
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))
    return np.column_stack([c * x + s * y, -s * x + c * y, z])


def pinhole_depth(
    boxes, camera_mm, rotation, fx: float, fy: float, cx: float, cy: float, width: int, height: int
) -> np.ndarray:
    """A pinhole depth image (height, width) of the floor z = 0 and upright boxes, each
    ``(centre (x, y) mm, (l, w, h) mm, yaw deg)`` resting on the floor. Depth is the camera-frame
    z of the nearest hit (exact: a slab test per box in its own frame)."""
    v, u = np.mgrid[0:height, 0:width].astype(float)
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1) @ rotation.T
    origin = np.asarray(camera_mm, float)
    # The camera frame's z of a hit at ray parameter t is t: each ray has camera z = 1.
    depth = np.where(rays[..., 2] < 0, -origin[2] / np.minimum(rays[..., 2], -1e-12), np.inf)
    for (bx, by), (l, w, h), yaw in boxes:
        c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
        to_box = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # frame -> box
        o = to_box @ (origin - (bx, by, h / 2))
        d = rays @ to_box.T
        half = np.array([l, w, h]) / 2
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (-half - o) / d
            t1 = (half - o) / d
        near = np.nanmax(np.minimum(t0, t1), axis=-1)
        far = np.nanmin(np.maximum(t0, t1), axis=-1)
        hit = (near <= far) & (near > 0)
        depth = np.where(hit & (near < depth), near, depth)
    return np.where(np.isfinite(depth), depth, np.nan)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


class LiveServer:
    """uvicorn serving the app in a thread of this process."""

    def __init__(self, workers: int = 1):
        import uvicorn  # the cell extra: only the tests that serve need it

        from packlab.cell.app import create_app
        from packlab.cell.server import make_backend
        from packlab.cell.settings import ServeSettings

        self.backend = make_backend(ServeSettings(workers=workers))
        self.port = free_port()
        config = uvicorn.Config(
            create_app(self.backend, "plan-fast"), port=self.port, log_level="warning"
        )
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> str:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            assert time.monotonic() < deadline, "the server did not start"
            time.sleep(0.05)
        return f"http://127.0.0.1:{self.port}"

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=30)
        self.backend.shutdown()
