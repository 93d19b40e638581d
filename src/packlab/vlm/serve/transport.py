"""HTTP POST with a deadline on the whole exchange, for the ``endpoint`` policy (stdlib only).

:func:`http_post` connects, sends, waits and reads the complete answer within one wall-clock
deadline: a watchdog shuts the socket at the deadline, so a server that accepts and never
answers, or trickles bytes, cannot hold a step longer (host-name lookup is the one part outside
it). It returns any complete answer whatever its status (:class:`HTTPReply`) and raises
:class:`TransportError` (retryable, one line) when none arrived.
"""

from __future__ import annotations

import http.client
import json
import socket
import ssl
import threading
import urllib.parse
from dataclasses import dataclass

#: Largest response body read (an answer is a few hundred bytes; images never come back).
MAX_RESPONSE_BYTES = 16 << 20


class TransportError(Exception):
    """One try failed before a complete HTTP answer arrived (retryable)."""


@dataclass(frozen=True, slots=True)
class HTTPReply:
    """A complete HTTP answer."""

    status: int
    reason: str  # the status line's reason phrase
    body: bytes  # at most max_bytes
    oversized: bool = False  # the body was longer than max_bytes (and was cut)

    def server_reason(self) -> str:
        """The server's own message, one line: ``error.message`` of an OpenAI-style error body,
        else the start of the body, else the status line's reason phrase."""
        text = self.body[:4000].decode("utf-8", "replace")
        try:
            err = json.loads(text).get("error")
            message = err.get("message") if isinstance(err, dict) else err
        except (ValueError, AttributeError, RecursionError):
            message = None
        message = message if isinstance(message, str) and message.strip() else text or self.reason
        return " ".join(message.split())[:300]


def _describe(exc: BaseException) -> str:
    """One line for a failed try."""
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused"
    if isinstance(exc, socket.gaierror):
        return f"cannot resolve the host name ({exc.strerror or exc})"
    if isinstance(exc, http.client.RemoteDisconnected):
        return "the server closed the connection without answering"
    if isinstance(exc, http.client.IncompleteRead):
        return "the answer was cut short"
    if isinstance(exc, ConnectionResetError):
        return "connection reset by the server"
    if isinstance(exc, ssl.SSLError):
        return f"TLS error: {exc.reason or exc}"
    text = (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)) or ""
    return "connection failed: " + (" ".join(text.split()) or type(exc).__name__)


def _read_capped(resp: http.client.HTTPResponse, max_bytes: int) -> tuple[bytes, bool]:
    """(up to ``max_bytes`` of the body, whether there was more)."""
    chunks: list[bytes] = []
    size = 0
    while size <= max_bytes:
        chunk = resp.read(min(65536, max_bytes + 1 - size))
        if not chunk:
            if resp.length:  # http.client returns a short body quietly: less than Content-Length
                raise http.client.IncompleteRead(b"".join(chunks), resp.length)
            break
        chunks.append(chunk)
        size += len(chunk)
    body = b"".join(chunks)
    return body[:max_bytes], len(body) > max_bytes


def http_post(
    url: str,
    body: bytes,
    deadline_s: float,
    headers: dict[str, str] | None = None,
    max_bytes: int = MAX_RESPONSE_BYTES,
) -> HTTPReply:
    """POST ``body`` and return the complete answer, whatever its status, within ``deadline_s``.

    The deadline covers connecting, sending, waiting and reading the whole body: a watchdog
    timer shuts the socket down when it passes, which wakes any blocked read or write (the
    socket's own timeout would only bound each read, so a trickling server could hold it for
    ever). Raises :class:`TransportError` when no complete answer arrived in time.
    """
    parts = urllib.parse.urlsplit(url)
    path = (parts.path or "/") + (f"?{parts.query}" if parts.query else "")
    conn_cls = (
        http.client.HTTPSConnection if parts.scheme == "https" else http.client.HTTPConnection
    )
    conn = conn_cls(parts.hostname or "", parts.port, timeout=deadline_s)
    expired = threading.Event()

    def expire() -> None:
        expired.set()
        sock = conn.sock
        if sock is not None:
            try:  # the plain socket's shutdown, also under TLS: wakes the blocked call
                socket.socket.shutdown(sock, socket.SHUT_RDWR)
            except OSError:
                pass

    watchdog = threading.Timer(deadline_s, expire)
    watchdog.daemon = True
    watchdog.start()
    try:
        conn.request("POST", path, body=body, headers=headers or {})
        resp = conn.getresponse()
        data, oversized = _read_capped(resp, max_bytes)
        status, reason = resp.status, resp.reason
    except (OSError, http.client.HTTPException, ValueError) as e:
        # ValueError: a TLS socket used after the watchdog shut it.
        if expired.is_set() or isinstance(e, TimeoutError):
            raise TransportError(
                f"no complete answer within the {deadline_s:g} s deadline"
            ) from None
        raise TransportError(_describe(e)) from None
    finally:
        watchdog.cancel()
        conn.close()
    if expired.is_set():  # a body read "to the end" may have ended at the shutdown
        raise TransportError(f"no complete answer within the {deadline_s:g} s deadline")
    return HTTPReply(status, reason, data, oversized)
