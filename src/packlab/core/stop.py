"""Stop requests: SIGINT and SIGTERM to a long-running command end it cleanly.

A terminal's Ctrl-C reaches the whole process group, but schedulers and supervisors (``timeout``,
systemd, a container runtime, a job scheduler's cancel) signal the main process alone. Python's
default SIGTERM action ends the process at once, with no ``finally`` block run: a process
pool's workers would be left running as orphans. Inside :func:`stop_handlers` both
signals raise :class:`StopRequested` in the main thread, so every cleanup path that already
handles Ctrl-C (stop the workers, close the record file, log the invocation) runs for SIGTERM
too, and the command exits with ``128 + signal number`` (130 for SIGINT, 143 for SIGTERM).

A second signal while the first is being handled ends the process at once with the signal's
default action: a user who asks twice means it. Worker processes do not depend on this
cleanup: each is tied to its parent's life (``packlab.executors``), so even a SIGKILL of the
main process leaves none behind.

SIGINT is handled even when the process started with it ignored, which a non-interactive
shell does for the commands it starts in the background (``cmd &`` in a script): a scheduler
that stops such a job with SIGINT would otherwise not stop it at all.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Collection, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from types import FrameType

from packlab.core.errors import EXIT_INTERRUPTED, EXIT_TERMINATED

#: The signals that ask a command to stop.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopRequested(KeyboardInterrupt):
    """A stop signal arrived. A KeyboardInterrupt, so code written for Ctrl-C cleans up the same
    way, and a policy's ``except Exception`` cannot swallow it."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(f"stopped by {signal.Signals(signum).name}")

    @property
    def exit_code(self) -> int:
        """The shell's convention for a process ended by a signal: 128 + its number."""
        return EXIT_TERMINATED if self.signum == signal.SIGTERM else EXIT_INTERRUPTED


_stopping = False
#: The stop signal received inside ``stop_handlers`` (None: none yet). Kept apart from the
#: exception because library code between the handler and the command may re-raise it as a plain
#: KeyboardInterrupt (Ray's waits do), which would lose which signal it was.
_received: int | None = None


def _on_stop_signal(signum: int, frame: FrameType | None) -> None:
    global _stopping, _received
    if _stopping:
        # Asked again while cleaning up: end now. Workers die with this process (executors).
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    _stopping, _received = True, signum
    raise StopRequested(signum)


@contextmanager
def stop_handlers() -> Iterator[None]:
    """While inside, SIGINT and SIGTERM raise :class:`StopRequested` in the main thread; the
    previous handlers come back on leaving (a test calling the CLI in-process keeps its own).
    A no-op outside the main thread: Python delivers signals to the main thread only."""
    global _stopping, _received
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _stopping, _received = False, None
    previous = {signum: signal.signal(signum, _on_stop_signal) for signum in STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def descendants(pid: int, skip: Collection[int] = ()) -> list[int]:
    """The processes ``pid`` started and theirs (Linux: read from /proc; elsewhere none),
    without those in ``skip`` and what they started."""
    proc = Path("/proc")
    if not proc.is_dir():
        return []
    children: dict[int, list[int]] = {}
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # ended meanwhile
            continue
        # The name is in parentheses and may hold anything: the fields start after the last ')'.
        fields = stat.rsplit(")", 1)[1].split()
        if fields[0] != "Z":
            children.setdefault(int(fields[1]), []).append(int(entry.name))
    found: list[int] = []
    skipped = set(skip)
    todo = [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            if child in skipped:
                continue
            found.append(child)
            todo.append(child)
    return found


def clock_ticks_since_boot() -> int | None:
    """Now, in the clock ticks since boot that /proc gives process start times in (None where
    there is no /proc)."""
    try:
        uptime_s = float(Path("/proc/uptime").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return int(uptime_s * os.sysconf("SC_CLK_TCK"))


def started_at_ticks(pid: int) -> int | None:
    """When ``pid`` started, in clock ticks since boot (None when it is gone or unknown)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return int(stat.rsplit(")", 1)[1].split()[19])  # field 22 of stat: starttime


def holding_files_under(directory: str | os.PathLike[str]) -> list[int]:
    """The processes (Linux, this user's) with a file open under ``directory``: a library's
    helpers that rename themselves and outlive their parent are still found by the logs they
    keep open (Ray's agents in their session directory). Empty elsewhere."""
    proc, root = Path("/proc"), str(Path(directory))
    if not proc.is_dir() or not root.startswith("/"):
        return []
    found = []
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            targets = [os.readlink(fd) for fd in (entry / "fd").iterdir()]
        except OSError:  # ended meanwhile, or another user's
            continue
        if any(t == root or t.startswith(root + "/") for t in targets):
            found.append(int(entry.name))
    return found


def is_alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie has exited; only its parent's wait is missing)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def end_processes(pids: Collection[int], grace_s: float = 1.0) -> None:
    """SIGTERM each of ``pids``, then SIGKILL those still running after ``grace_s``. Followed by
    pid, not by parentage: a process whose parent ended meanwhile is still found."""
    for pid in pids:
        with suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGTERM)
    until = time.monotonic() + grace_s
    left = [pid for pid in pids if is_alive(pid)]
    while left and time.monotonic() < until:
        time.sleep(0.05)
        left = [pid for pid in left if is_alive(pid)]
    for pid in left:
        with suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGKILL)


#: Linux's prctl option that makes a process the new parent of its orphaned descendants.
_PR_SET_CHILD_SUBREAPER = 36


def adopt_orphans(on: bool) -> bool:
    """Make this process (Linux) the parent of any of its descendants orphaned while ``on``,
    instead of init: a library helper whose own parent ended first (Ray's agents once their
    raylet is gone) stays this process's descendant, so a cleanup by parentage still finds it.
    Returns whether the kernel accepted the setting (False elsewhere)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return bool(libc.prctl(_PR_SET_CHILD_SUBREAPER, int(on), 0, 0, 0) == 0)
    except (OSError, AttributeError):
        return False


def reap(pids: Collection[int]) -> None:
    """Collect the exit status of those of ``pids`` that are this process's ended children
    (adopted orphans are nobody else's to wait for): no zombie is left for a later process
    listing to trip over. Never blocks, never touches other children."""
    for pid in pids:
        with suppress(ChildProcessError, OSError):
            os.waitpid(pid, os.WNOHANG)


def end_descendants(grace_s: float = 1.0, keep: Collection[int] = ()) -> int:
    """End every process this one started that still runs, and theirs, except those in ``keep``
    (the ones that were there before the command: a caller that runs the CLI in-process, a test
    session with its Ray cluster, must keep its own): SIGTERM, then SIGKILL for any left after
    ``grace_s``. Returns how many there were.

    The last step of a stopped command. Executors stop their own workers, but a library's
    helper processes can outlive an interruption that lands while they start (a forkserver
    still importing torch for a vectorised environment that was never built, so never closed),
    and would otherwise end seconds after the command or never.
    """
    # Not what a kept process started since (a test session's Ray cluster starts and ends its
    # workers at will: ending one of them, or an agent it restarted, can end the cluster and
    # with it the caller, whose Ray driver exits when its raylet is gone).
    pids = descendants(os.getpid(), skip=keep)
    end_processes(pids, grace_s)
    return len(pids)


def exit_code_of(interrupt: KeyboardInterrupt) -> int:
    """128 + the signal for a StopRequested; 130 (SIGINT) for a plain KeyboardInterrupt."""
    if isinstance(interrupt, StopRequested):
        return interrupt.exit_code
    if _received is not None:  # a stop signal came back as a plain KeyboardInterrupt
        return StopRequested(_received).exit_code
    return EXIT_INTERRUPTED


def describe_stop(interrupt: KeyboardInterrupt) -> str:
    """ "stopped by SIGTERM" (or SIGINT) for a stop signal, "interrupted" for a plain Ctrl-C."""
    if isinstance(interrupt, StopRequested):
        return str(interrupt)
    if _received is not None:
        return str(StopRequested(_received))
    return "interrupted"


__all__ = [
    "STOP_SIGNALS",
    "StopRequested",
    "adopt_orphans",
    "clock_ticks_since_boot",
    "descendants",
    "describe_stop",
    "end_descendants",
    "end_processes",
    "exit_code_of",
    "is_alive",
    "reap",
    "started_at_ticks",
    "stop_handlers",
]
