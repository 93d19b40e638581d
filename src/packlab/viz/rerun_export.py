"""Send an episode to the Rerun viewer, or save it as an .rrd file when no viewer is running.

``export_live`` runs a policy on a case and streams each step as it is taken; ``export_replay``
replays a bench record (see ``packlab.viz.episode_frames`` for what a replay shows). Where the
recording goes is a ``ViewerTarget``: a file (the default), a viewer spawned for it, or a viewer
already running at a gRPC URL; when the viewer cannot be reached the recording is saved to the
file instead and the result says so. ``packlab.viz.rerun_log`` says what a recording holds.
rerun-sdk (the ``viewer`` extra) is imported only when a recording is opened.
"""

from __future__ import annotations

import os
import socket
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from packlab.core.choices import DEFAULT_SIDES, SideNames
from packlab.core.errors import ConfigError
from packlab.core.packing_protocol import BUFFER, PackingProtocol
from packlab.core.records import EpisodeOk
from packlab.core.types import Case, Container
from packlab.metrics import EpisodeMetrics
from packlab.viz.episode_frames import Frame, live_frames, replay_frames
from packlab.viz.options import DEFAULT_VIEWER_URL
from packlab.viz.rerun_log import (
    EpisodeInfo,
    EpisodeLogger,
    blueprint,
    metrics_markdown,
    replay_note,
    rerun_module,
)

if TYPE_CHECKING:
    import rerun as rr

#: The application id recordings are filed under in the viewer.
APPLICATION_ID = "packlab"
DEFAULT_VIEWER_PORT = 9876
#: Seconds to wait for a viewer's port: a running one answers at once, a spawned one needs a
#: moment to start.
CONNECT_WAIT_S, SPAWN_WAIT_S = 0.5, 5.0


@dataclass(frozen=True, slots=True)
class ViewerTarget:
    """Where a recording goes: an .rrd file, a viewer spawned for it, or a running viewer.

    ``out`` is written when ``save`` is set, and instead of the stream when the viewer cannot
    be reached (nothing listens at ``connect``, or the spawned viewer did not start).
    """

    out: Path
    save: bool = True
    spawn: bool = False
    connect: str | None = None  # a viewer's gRPC URL, e.g. DEFAULT_VIEWER_URL

    def __post_init__(self) -> None:
        if self.spawn and self.connect is not None:
            raise ConfigError("viewer: --spawn starts a viewer, --connect joins one; not both")
        if not (self.save or self.spawn or self.connect is not None):
            raise ConfigError("viewer: nothing to do (no file to save and no viewer to stream to)")
        if self.connect is not None:
            _host_port(self.connect)  # a bad URL is an error now, not after the episode ran

    @property
    def url(self) -> str | None:
        """The viewer URL streamed to (None: file only)."""
        if self.connect is not None:
            return self.connect
        return DEFAULT_VIEWER_URL if self.spawn else None


def _host_port(url: str) -> tuple[str, int]:
    parts = urlsplit(url)
    try:
        port = parts.port or DEFAULT_VIEWER_PORT
    except ValueError:
        raise ConfigError(f"connect = {url!r}: bad port") from None
    if not parts.hostname or "://" not in url:
        raise ConfigError(f"connect = {url!r}: not a viewer URL (e.g. {DEFAULT_VIEWER_URL})")
    return parts.hostname, port


def viewer_listening(url: str, timeout_s: float = CONNECT_WAIT_S) -> bool:
    """Whether something accepts connections at a viewer URL's host and port."""
    try:
        with socket.create_connection(_host_port(url), timeout=timeout_s):
            return True
    except OSError:
        return False


def display_available() -> bool:
    """Whether a native viewer window can open (on Linux: an X11 or Wayland display is set)."""
    if not sys.platform.startswith("linux"):
        return True
    return any(os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"))


@dataclass(frozen=True, slots=True)
class Opened:
    """An open recording and what it is sent to."""

    stream: rr.RecordingStream
    saved: Path | None  # the .rrd file written (None: streamed only)
    streamed_to: str | None  # the viewer URL streamed to (None: file only)
    note: str  # "" or why the target changed (no viewer there: saved instead)


def open_recording(
    target: ViewerTarget, name: str, container: Container, log_time: bool = True
) -> Opened:
    """A recording stream sending to ``target``. ``log_time=False`` leaves out rerun's
    wall-clock timeline (meaningless for a replay, whose only clock is the step)."""
    rr = rerun_module()
    stream = rr.RecordingStream(APPLICATION_ID)
    if not log_time:
        rr.set_log_time_enabled(False, recording=stream)
    url, problem = target.url, ""
    if target.spawn and not display_available():
        # A viewer without a display binds its port, then dies: do not stream into that.
        url, problem = None, "no display to open a viewer on (DISPLAY and WAYLAND_DISPLAY unset)"
    elif target.spawn:
        stream.spawn(port=DEFAULT_VIEWER_PORT, connect=False)
    wait = SPAWN_WAIT_S if target.spawn else CONNECT_WAIT_S
    if url is not None and not viewer_listening(url, wait):
        what = "the spawned viewer did not start" if target.spawn else f"no Rerun viewer at {url}"
        url, problem = None, what
    note = f"{problem}; saving to {target.out} instead" if problem else ""
    save = target.save or url is None
    sinks: list[Any] = [rr.GrpcSink(url)] if url else []
    if save:
        target.out.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(target.out)))
    stream.set_sinks(*sinks, default_blueprint=blueprint(rr, container))
    stream.send_recording_name(name)
    return Opened(stream, target.out if save else None, url, note)


def close_recording(opened: Opened) -> None:
    """Flush everything to the sinks and close them (the .rrd file is complete after this)."""
    opened.stream.flush()
    opened.stream.disconnect()


@dataclass(frozen=True, slots=True)
class Exported:
    """What an export did."""

    saved: Path | None
    streamed_to: str | None
    note: str  # "" or why the target changed
    steps: int  # frames logged, one per step
    metrics: EpisodeMetrics | None  # the episode's final scores (None: it did not finish)
    exact: bool | None  # a replay shows its record's episode (None: a live episode)
    method: str = "live"  # or how a replay got its frames (episode_frames.RECORDED_POSES ...)


def _log_frames(logger: EpisodeLogger, frames: Iterable[Frame]) -> EpisodeMetrics | None:
    metrics = None
    for frame in frames:
        logger.log_frame(frame)
        metrics = frame.metrics or metrics
    return metrics


def export_live(
    case: Case,
    policy: Any,
    policy_name: str,
    target: ViewerTarget,
    seed: int = 0,
    backend: str = "mujoco",
    physics: Any = None,
) -> Exported:
    """Run ``policy`` on ``case`` and send each step to ``target`` as it is taken."""
    info = EpisodeInfo(case, policy_name, seed, backend, "live")
    name = f"{case.episode_id} {policy_name} seed {seed} (live)"
    opened = open_recording(target, name, case.container)
    try:
        logger = EpisodeLogger(opened.stream, info)
        logger.log_case()
        metrics = _log_frames(logger, live_frames(case, policy, seed, backend, physics))
        if metrics is not None:
            logger.log_summary(metrics_markdown(metrics))
    finally:
        close_recording(opened)
    return Exported(opened.saved, opened.streamed_to, opened.note, logger.frames, metrics, None)


def export_replay(
    case: Case,
    record: EpisodeOk,
    target: ViewerTarget,
    source: str,
    physics: Any = None,
    resimulate: bool = False,
    sides: SideNames = DEFAULT_SIDES,
    protocol: PackingProtocol = BUFFER,
) -> Exported:
    """Send a bench record's episode to ``target``, step by step (``replay_frames`` says how
    the steps are rebuilt: from the record's poses, or by stepping its actions again, under
    the run's side names ``sides`` and its ``protocol``)."""
    replay = replay_frames(case, record, physics, resimulate, sides, protocol)
    info = EpisodeInfo(case, record.policy, record.seed, record.backend, source)
    name = f"{case.episode_id} {record.policy} seed {record.seed}"
    opened = open_recording(target, name, case.container, log_time=False)
    try:
        logger = EpisodeLogger(opened.stream, info)
        logger.log_case()
        for frame in replay.frames:
            logger.log_frame(frame)
            logger.log_mean_policy_ms(frame.step.step_index, replay.mean_policy_s)
        metrics = replay.frames[-1].metrics
        if metrics is not None:
            logger.log_summary(metrics_markdown(metrics, record.metrics, replay_note(replay)))
    finally:
        close_recording(opened)
    return Exported(
        opened.saved,
        opened.streamed_to,
        opened.note,
        logger.frames,
        metrics,
        replay.exact,
        replay.method,
    )


__all__ = [
    "APPLICATION_ID",
    "DEFAULT_VIEWER_URL",
    "Exported",
    "Opened",
    "ViewerTarget",
    "close_recording",
    "export_live",
    "export_replay",
    "open_recording",
    "viewer_listening",
]
