"""packlab.core.stop in this process: what a stop signal raises, the exit codes, handlers put
back, and the last-resort end of processes a command left running. The end-to-end behaviour of
each command under real signals is tests/test_stop_signals.py."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from packlab.core.errors import EXIT_INTERRUPTED, EXIT_TERMINATED
from packlab.core.stop import (
    StopRequested,
    clock_ticks_since_boot,
    descendants,
    describe_stop,
    end_descendants,
    exit_code_of,
    started_at_ticks,
    stop_handlers,
)


@pytest.mark.parametrize(
    ("signum", "code"), [(signal.SIGTERM, EXIT_TERMINATED), (signal.SIGINT, EXIT_INTERRUPTED)]
)
def test_a_stop_signal_raises_stop_requested_with_its_exit_code(signum, code):
    with pytest.raises(StopRequested) as caught, stop_handlers():
        os.kill(os.getpid(), signum)
        time.sleep(5)  # the handler raises as soon as the interpreter runs it
    assert caught.value.signum == signum
    assert exit_code_of(caught.value) == code
    assert isinstance(caught.value, KeyboardInterrupt)  # Ctrl-C's cleanup paths run


def test_a_plain_keyboard_interrupt_is_exit_130():
    assert exit_code_of(KeyboardInterrupt()) == EXIT_INTERRUPTED == 130
    assert EXIT_TERMINATED == 128 + signal.SIGTERM


def test_the_previous_handlers_come_back():
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    with stop_handlers():
        assert signal.getsignal(signal.SIGTERM) not in (signal.SIG_DFL, before[0])
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


def test_sigint_is_handled_even_when_inherited_ignored():
    """A shell starts `cmd &` with SIGINT ignored; the command must still stop on it."""
    code = (
        "import os, signal, time\n"
        "from packlab.core.stop import StopRequested, stop_handlers\n"
        "assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN\n"
        "try:\n"
        "    with stop_handlers():\n"
        "        os.kill(os.getpid(), signal.SIGINT); time.sleep(5)\n"
        "except StopRequested as e:\n"
        "    raise SystemExit(e.exit_code)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == EXIT_INTERRUPTED, done.stderr


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_end_descendants_ends_a_child_that_ignores_sigterm():
    before = descendants(os.getpid())  # the session's own (a Ray cluster) must survive
    child = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); time.sleep(60)",
        ]
    )
    try:
        time.sleep(0.5)  # let it install its handler
        started = time.monotonic()
        assert end_descendants(grace_s=0.5, keep=before) == 1
        assert child.wait(timeout=5) == -signal.SIGKILL
        assert time.monotonic() - started < 5
    finally:
        if child.poll() is None:
            child.kill()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_caller_keeps_the_processes_it_had_before_the_command(monkeypatch, capsys):
    """The CLI run in-process (a test session with its Ray cluster, a notebook) and stopped must
    end only what the command started: ending the caller's own processes took a test session's
    Ray cluster down with it."""
    from packlab.cli import main as cli

    theirs = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    ours: list[subprocess.Popen] = []

    def command(args):
        ours.append(subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]))
        raise KeyboardInterrupt

    try:
        parser = cli.build_parser()
        args = parser.parse_args(["inspect-data", "x"])
        monkeypatch.setattr(args, "func", command)
        monkeypatch.setattr(cli, "build_parser", lambda: _Fixed(args))
        assert cli.main(["inspect-data", "x"]) == EXIT_INTERRUPTED
        assert ours[0].wait(timeout=5) is not None  # the command's own child was ended
        assert theirs.poll() is None  # the caller's was kept
    finally:
        for proc in (theirs, *ours):
            if proc.poll() is None:
                proc.kill()
                proc.wait()


class _Fixed:
    """A parser stand-in that returns parsed arguments whose ``func`` a test replaced."""

    def __init__(self, args):
        self.args = args

    def parse_args(self, argv):
        return self.args


def test_a_stop_signal_re_raised_as_a_plain_keyboard_interrupt_keeps_its_exit_code():
    """Ray's waits turn any exception from a signal handler into a plain KeyboardInterrupt."""
    with pytest.raises(KeyboardInterrupt) as caught, stop_handlers():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        except StopRequested:
            raise KeyboardInterrupt from None
    assert not isinstance(caught.value, StopRequested)
    assert exit_code_of(caught.value) == EXIT_TERMINATED
    assert describe_stop(caught.value) == "stopped by SIGTERM"
    with stop_handlers():  # a new command starts with no signal received
        assert exit_code_of(KeyboardInterrupt()) == EXIT_INTERRUPTED


def test_processes_are_found_by_the_files_they_keep_open(tmp_path):
    """``holding_files_under``: a helper that renamed itself and lost its parent is still
    found by a file it keeps open under the directory (as Ray's agents keep their session's
    logs), and nothing is found under a directory no process uses."""
    from packlab.core.stop import holding_files_under

    (tmp_path / "ours").mkdir()
    (tmp_path / "other").mkdir()
    log = tmp_path / "ours" / "agent.log"
    code = f"f = open({str(log)!r}, 'w'); import time; time.sleep(30)"
    child = subprocess.Popen([sys.executable, "-c", code])
    try:
        for _ in range(100):  # until the child has opened its file
            if log.exists() and child.pid in holding_files_under(tmp_path / "ours"):
                break
            time.sleep(0.05)
        assert child.pid in holding_files_under(tmp_path / "ours")
        assert child.pid in holding_files_under(tmp_path)
        assert child.pid not in holding_files_under(tmp_path / "other")
        assert holding_files_under("relative/path") == []
    finally:
        child.kill()
        child.wait()
    assert child.pid not in holding_files_under(tmp_path / "ours")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_what_a_kept_process_starts_is_kept_too():
    """A caller's process (a test session's Ray raylet) starts and ends its own children at
    will; ending one of them could end the caller's cluster, so they are skipped with it."""
    code = (
        "import subprocess, sys, time; "
        "subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(30)']); "
        "time.sleep(30)"
    )
    parent = subprocess.Popen([sys.executable, "-c", code])
    try:
        deadline = time.monotonic() + 10
        while len(descendants(parent.pid)) < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        grandchild = descendants(parent.pid)
        assert len(grandchild) == 1
        assert parent.pid in descendants(os.getpid())
        assert grandchild[0] in descendants(os.getpid())
        assert parent.pid not in descendants(os.getpid(), skip={parent.pid})
        assert grandchild[0] not in descendants(os.getpid(), skip={parent.pid})
    finally:
        for pid in descendants(parent.pid):
            os.kill(pid, signal.SIGKILL)
        parent.kill()
        parent.wait()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_start_ticks_order_processes_by_age():
    before = clock_ticks_since_boot()
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        assert started_at_ticks(os.getpid()) <= before <= started_at_ticks(child.pid)
        assert started_at_ticks(2**22 + 12345) is None
    finally:
        child.kill()
        child.wait()


_ORPHAN_SCRIPT = """
import os, subprocess, sys, time
from packlab.core.stop import adopt_orphans, descendants, end_processes, is_alive, reap
adopted = adopt_orphans(sys.argv[1] == "adopt")
# A child that starts a long-lived grandchild, prints its pid and exits: the grandchild's
# parent is gone (as Ray's agents once their raylet has ended).
child = subprocess.run(
    [sys.executable, "-c",
     "import subprocess, sys; "
     "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'], "
     "stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL); "
     "print(p.pid)"],
    capture_output=True, text=True, check=True,
)
orphan = int(child.stdout)
found = orphan in descendants(os.getpid())
end_processes([orphan])
reap([orphan])
print(adopted, found, is_alive(orphan), os.path.exists(f"/proc/{orphan}"))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl and /proc")
@pytest.mark.parametrize("mode", ["adopt", "leave"])
def test_an_adopted_orphan_stays_a_descendant_and_is_reaped(mode):
    """``adopt_orphans``: a grandchild whose parent ended is still this process's descendant
    (so a cleanup by parentage ends it) and, once ended, leaves no zombie; without it, the
    orphan belongs to init and a parentage search misses it (the control)."""
    out = subprocess.run(
        [sys.executable, "-c", _ORPHAN_SCRIPT, mode],
        capture_output=True, text=True, check=True, timeout=60,
    )  # fmt: skip
    adopted, found, alive, listed = out.stdout.split()
    if mode == "adopt":
        assert (adopted, found, alive, listed) == ("True", "True", "False", "False")
    else:
        assert (found, alive) == ("False", "False")
