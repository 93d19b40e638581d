"""Test-only policies that misbehave on purpose: a dead server, a hang, a dying worker.

Registered by ``register_all()`` (the fault tests' fixture, or a Ray worker's setup hook) and
removed by ``unregister_all()``, so other tests never see them in the registry.
"""

from __future__ import annotations

import os
import signal
import socket
import time

from packlab.core.errors import EndpointUnavailable
from packlab.core.types import Action, Case, Observation
from packlab.policies.registry import _RUNTIME as _FACTORIES
from packlab.policies.registry import register_policy


class Unreachable:
    """Like the endpoint policy against a dead server: every act() is a transport failure,
    while ``Unreachable.down`` is True (workers fork from the test, so flipping it there
    before a run brings the "server" back)."""

    name = "test-unreachable"
    down = True

    def reset(self, case: Case, seed: int) -> None:
        pass

    def act(self, observation: Observation) -> Action:
        if Unreachable.down:
            raise EndpointUnavailable("http://127.0.0.1:9/v1: connection refused after 3 tries")
        return Action(0, 0, 0, 0)


class Sleeper:
    """Stuck in a blocking call that never returns (time.sleep)."""

    name = "test-sleep"

    def reset(self, case: Case, seed: int) -> None:
        pass

    def act(self, observation: Observation) -> Action:
        time.sleep(10**6)
        return Action(0, 0, 0, 0)


class Spinner:
    """Stuck in a Python loop of short waits (polling for something that never comes)."""

    name = "test-spin"

    def reset(self, case: Case, seed: int) -> None:
        pass

    def act(self, observation: Observation) -> Action:
        while True:
            time.sleep(0.01)


class SocketReader:
    """Stuck reading a socket whose peer never writes (a hung server)."""

    name = "test-socket-hang"

    def reset(self, case: Case, seed: int) -> None:
        self._pair = socket.socketpair()

    def act(self, observation: Observation) -> Action:
        self._pair[0].recv(1)
        return Action(0, 0, 0, 0)


class Deaf:
    """Ignores SIGALRM, then hangs: stands for code the alarm cannot interrupt (a C loop)."""

    name = "test-deaf"

    def reset(self, case: Case, seed: int) -> None:
        pass

    def act(self, observation: Observation) -> Action:
        signal.signal(signal.SIGALRM, signal.SIG_IGN)
        time.sleep(10**6)
        return Action(0, 0, 0, 0)


class Suicide:
    """Kills its own process, like the out-of-memory killer would."""

    name = "test-sigkill"

    def reset(self, case: Case, seed: int) -> None:
        pass

    def act(self, observation: Observation) -> Action:
        os.kill(os.getpid(), signal.SIGKILL)
        return Action(0, 0, 0, 0)


POLICIES = (Unreachable, Sleeper, Spinner, SocketReader, Deaf, Suicide)


def register_all() -> None:
    for cls in POLICIES:
        register_policy(cls.name)(cls)


def unregister_all() -> None:
    for cls in POLICIES:
        _FACTORIES.pop(cls.name, None)
    Unreachable.down = True
