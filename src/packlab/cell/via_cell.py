"""The bench's episodes played through a running cell service (``packlab bench --via-cell URL``).

The bench keeps the episode: the MuJoCo scene, the simulated depth cameras, the noisy place
skill and the records. The policy lives in the service and sees only what a cell sends it: per
step the container camera's and the buffer camera's noisy depth images (the ones the in-process
perceived mode renders and reads), their calibrations, and how many boxes are still to come.
The service segments and measures the buffer, builds the heightmap and asks its policy; the
bench maps the answer back onto the episode and carries it out as the in-process run does.

- :class:`SensorTap` wraps the run's perceiver and keeps the latest images and segments;
- :class:`CellPolicy` stands where the in-process policy stands in ``run_episode``: a service
  session per episode, a step per decision;
- :func:`check_service` refuses, in one line, a URL where no service answers, a service of
  another packlab version, or one that cannot serve a policy the bench runs.

Which true box the service's answer names is the simulator's bookkeeping, as in perceived mode:
the service names a box by its segment in the buffer image, and the robot picks the box under
that segment (``sensing.buffer``). The service and the in-process perceived mode list the
buffer's box-like segments in the same order, their labels' in the image, so the two runs' records
are the same, times aside (docs/cell.md).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import replace
from typing import Any, Protocol

import httpx
import numpy as np

import packlab
from packlab.cell import schema
from packlab.cell.client import CellClient, CellServiceError
from packlab.cell.simulated import simulated_camera
from packlab.core.choices import DEFAULT_SIZE_PRIOR, SizePrior
from packlab.core.errors import ConfigError, EndpointUnavailable
from packlab.core.types import Action, Container, Observation, Unparsable
from packlab.sim.modes import EpisodeModes, SensingPerceiver, perception_of
from packlab.sim.replan import Perception, Scene
from packlab.sim.sensing import PerceivedState

#: How long a step may take the service before the bench gives up on it (s): the planner's
#: slowest decisions on a busy machine, and the images' transfer.
STEP_TIMEOUT_S = 120.0


class CellStart(Protocol):
    """What the session is opened with at an episode's start: what a cell knows before its
    first look (a case or the episode's start both have it)."""

    @property
    def container(self) -> Container: ...

    @property
    def buffer_size(self) -> int: ...


class SensorTap:
    """A perceiver that perceives as ``perceiver`` does and keeps what it made last: the noisy
    images, the buffer's segments and which shown box each stands for."""

    def __init__(self, perceiver: SensingPerceiver):
        self.perceiver = perceiver
        self.last: PerceivedState | None = None

    def __call__(self, scene: Scene, rng: np.random.Generator) -> Perception:
        self.last = self.perceiver.perceived_state(scene, rng)
        return perception_of(self.last)


def tapped_modes(modes: EpisodeModes) -> tuple[EpisodeModes, SensorTap]:
    """``modes`` with the perceiver wrapped in a :class:`SensorTap` (perceived mode only: the
    service reads images, so the episode must render them)."""
    if not isinstance(modes.perceiver, SensingPerceiver):
        raise ConfigError(
            "via-cell: the service sees only depth images; run with --observation perceived "
            "(e.g. --observation perceived --execution noisy --noise structured-light)"
        )
    if modes.perceiver.segmentation != "depth":
        raise ConfigError(
            "via-cell: the service segments the buffer from depth; drop --segmentation truth"
        )
    tap = SensorTap(modes.perceiver)
    return replace(modes, perceiver=tap), tap


class CellPolicy:
    """The policy ``name`` (with ``options``) as the cell service at ``client`` serves it.

    ``reset`` opens a session with what a cell knows (the container, the buffer's size, the
    run seed as the policy's seed); ``act`` sends the images ``tap`` holds for the current
    observation and returns the service's answer as the episode's action: the policy's own
    answer with its box index turned from the service's segment order into the episode's
    shown order. ``close`` ends the session.
    """

    def __init__(
        self,
        client: CellClient,
        name: str,
        options: Mapping[str, Any],
        tap: SensorTap,
        preset: schema.PresetName,
        size_prior: SizePrior = DEFAULT_SIZE_PRIOR,
    ):
        self.name = name
        self._client = client
        self._options = dict(options)
        self._tap = tap
        self._preset = preset
        self._size_prior = size_prior
        self._start: CellStart | None = None
        self._seed = 0
        self._session: str | None = None

    def reset(self, start: CellStart, seed: int) -> None:
        """A new episode in ``start``'s container; its session opens at the first step (with
        that step's cameras)."""
        self.close()
        self._start, self._seed = start, seed

    def act(self, observation: Observation) -> Action | Unparsable:
        state = self._tap.last
        if state is None or self._start is None:
            raise RuntimeError("CellPolicy.act before the episode perceived anything")
        buffer_camera = simulated_camera(state.buffer.image)
        if self._session is None:
            self._session = self._open(state, buffer_camera)
        answer = self._call(
            self._client.step,
            self._session,
            state.container_image.depth_mm,
            state.buffer.image.depth_mm,
            remaining=observation.remaining,
            buffer_camera=buffer_camera,
        )
        return episode_action(answer, state)

    def close(self) -> None:
        """End the episode's session (the service keeps a closed session's memory no longer)."""
        session, self._session = self._session, None
        if session is not None:
            try:
                self._client.close(session)
            except (CellServiceError, httpx.HTTPError):
                pass  # an idle session is closed by the service itself

    def _open(self, state: PerceivedState, buffer_camera: schema.Camera) -> str:
        assert self._start is not None
        container = self._start.container
        x, y, z = container.size_mm
        request = schema.SessionRequest(
            container=schema.ContainerSpec(
                size_mm=(x, y, z), cell_mm=container.cell_xy_mm, height_step_mm=container.cell_z_mm
            ),
            buffer_size=self._start.buffer_size,
            container_camera=simulated_camera(state.container_image),
            buffer_camera=buffer_camera,
            sensing=schema.Sensing(preset=self._preset, size_prior=self._size_prior),
            policy=self.name,
            policy_options=self._options,
            seed=self._seed,
        )
        opened = self._call(self._client.open, request)
        if opened.policy != self.name:
            raise ConfigError(
                f"via-cell: the service opened a session of policy {opened.policy!r}, "
                f"not the bench's {self.name!r}"
            )
        return opened.session_id

    @staticmethod
    def _call(method: Any, *args: Any, **kwargs: Any) -> Any:
        """``method``'s answer; a service that cannot be reached, or fails (5xx), is a transport
        failure of the episode, as a model server's is."""
        try:
            return method(*args, **kwargs)
        except httpx.HTTPError as exc:
            raise EndpointUnavailable(f"cell service: {type(exc).__name__}: {exc}") from exc
        except CellServiceError as exc:
            if exc.status >= 500:
                raise EndpointUnavailable(str(exc)) from exc
            raise


def episode_action(answer: schema.StepAnswer, state: PerceivedState) -> Action | Unparsable:
    """The episode's action for the service's ``answer`` to the step ``state`` perceived: the
    policy's own answer, its ``object_id`` (an index into the service's ``boxes``, the buffer
    image's box-like segments in label order) turned into the index of that segment among the
    boxes the episode shows (the same segments, less any that lies on no box: it names none,
    an index past the shown ones). An index the service's boxes do not have stays out of
    range."""
    action = answer.action
    if action is None:
        return Unparsable(text="", error="the cell service's policy gave no readable answer")
    if len(answer.boxes) != len(state.buffer.found):
        raise RuntimeError(
            f"the cell service found {len(answer.boxes)} boxes on the buffer image where the "
            f"simulated robot found {len(state.buffer.found)}: not the same perception"
        )
    listed = state.buffer.listed
    object_id = action.object_id
    if 0 <= object_id < len(answer.boxes):
        object_id = listed.index(object_id) if object_id in listed else len(listed)
    elif object_id >= 0:
        object_id += len(listed)  # out of range there, out of range here
    return Action(object_id=object_id, rotation=action.rotation, x=action.x, y=action.y)


def check_service(client: CellClient, url: str, policies: tuple[str, ...]) -> None:
    """ConfigError in one line unless the service at ``url`` answers, runs this packlab
    version, and serves every policy in ``policies``."""
    try:
        health = client.health()
        served = client.policies()
    except (httpx.HTTPError, CellServiceError) as exc:
        raise ConfigError(
            f"via-cell = {url!r}: no cell service answered ({type(exc).__name__}: {exc}); "
            "start one with `packlab cell serve`"
        ) from None
    if health.version != packlab.__version__:
        raise ConfigError(
            f"via-cell = {url!r}: the service runs packlab {health.version}, the bench "
            f"{packlab.__version__}; their records would not be comparable"
        )
    missing = [name for name in policies if name not in served.policies]
    if missing:
        raise ConfigError(
            f"via-cell = {url!r}: the service cannot serve {', '.join(map(repr, missing))} "
            f"(it serves {', '.join(served.policies)})"
        )


def cell_client(url: str) -> CellClient:
    """A client of the service at ``url`` with the bench's step timeout."""
    return CellClient(url, timeout_s=STEP_TIMEOUT_S)


def preflight_service(url: str, policies: tuple[str, ...]) -> None:
    """:func:`check_service` on a client of its own, before the bench starts its workers."""
    with cell_client(url) as client:
        check_service(client, url, policies)


@contextmanager
def served_policy(
    url: str, name: str, options: Mapping[str, Any], modes: EpisodeModes
) -> Iterator[tuple[CellPolicy, EpisodeModes]]:
    """One episode's :class:`CellPolicy` for policy ``name`` at the service at ``url``, and the
    ``modes`` that hand it the images; the session and the connection end with the block."""
    tapped, tap = tapped_modes(modes)
    assert isinstance(tap.perceiver, SensingPerceiver)
    with cell_client(url) as client:
        perceiver = tap.perceiver
        policy = CellPolicy(client, name, options, tap, perceiver.preset, perceiver.size_prior)
        try:
            yield policy, tapped
        finally:
            policy.close()


__all__ = [
    "STEP_TIMEOUT_S",
    "CellPolicy",
    "SensorTap",
    "cell_client",
    "check_service",
    "episode_action",
    "preflight_service",
    "served_policy",
    "tapped_modes",
]
