"""The LLM parser's HTTP transport: one POST within a wall-clock budget and a body-size cap, no redirects, its
failures typed as worth retrying (`Transient`) or final (`NoAnswer`). No message quotes what the server sent."""

from __future__ import annotations

import contextlib
import functools
import http.client
import socket
import threading
import time
import urllib.error
import urllib.request


class Transient(Exception):
    """A failure that may pass on retry: no connection, a timeout, HTTP 429 or 5xx."""

    def __init__(self, reason: str, retry_after: float | None = None):
        super().__init__(reason)
        self.retry_after = retry_after


class NoAnswer(Exception):
    """Retrying cannot help or time is up; the message says why (it becomes `fallback_reason`)."""

    def __init__(self, reason: str, json_mode_refused: bool = False, transport: bool = False):
        super().__init__(reason)
        self.json_mode_refused = json_mode_refused  # an HTTP 400/422 whose body names JSON mode
        self.transport = transport  # every attempt failed in transport: no connection, timeouts, 429, 5xx


def post(request: urllib.request.Request, timeout_s: float, deadline: float, max_body_bytes: int) -> bytes:
    """The response body, within `timeout_s` and the `time.monotonic()` `deadline`, at most `max_body_bytes`."""
    budget = min(timeout_s, deadline - time.monotonic())
    timed_out = f"timed out after {max(budget, 0):.1f} s"
    if budget <= 0:
        raise Transient(timed_out)
    with _Watchdog(budget) as watchdog:
        try:
            with _opener(watchdog).open(request, timeout=budget) as response:
                payload = _read_capped(response, max_body_bytes)
        except urllib.error.HTTPError as error:
            refused = error.code in (400, 422) and _names_json_mode(error)
            error.close()
            raise _http_failure(error, refused) from error
        except (OSError, http.client.HTTPException) as error:
            raise Transient(timed_out if watchdog.fired else _describe(error)) from error
        if watchdog.fired:  # the shut socket ended the body early: it is not the whole answer
            raise Transient(timed_out)
    return payload


def _read_capped(response: http.client.HTTPResponse, cap: int) -> bytes:
    """The body; NoAnswer past `cap` bytes (unread when Content-Length announces it)."""
    if (response.length or 0) > cap or len(payload := response.read(cap + 1)) > cap:
        raise NoAnswer(
            f"the response is larger than the {cap:,}-byte cap (max_body_bytes); "
            "is the base URL a chat-completions endpoint?"
        )
    return payload


class _Watchdog:
    """Shuts a request's socket down when its budget is spent, so that no read outlives it.

    A socket timeout bounds each read, not the request: a server that sends a byte every
    second would hold the parse for ever.
    """

    def __init__(self, seconds: float):
        self.fired = False
        self._sockets: list[socket.socket] = []
        self._lock = threading.Lock()
        self._timer = threading.Timer(seconds, self._fire)
        self._timer.daemon = True

    def __enter__(self) -> _Watchdog:
        self._timer.start()
        return self

    def __exit__(self, *exc_info) -> None:
        self._timer.cancel()

    def watch(self, sock: socket.socket) -> None:
        with self._lock:
            self._sockets.append(sock)
            if self.fired:
                _shut(sock)

    def _fire(self) -> None:
        with self._lock:
            self.fired = True
            for sock in self._sockets:
                _shut(sock)


def _shut(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):  # already closed: the request ended on its own
        sock.shutdown(socket.SHUT_RDWR)


class _WatchedConnection(http.client.HTTPConnection):
    """Hands its socket to the watchdog once connected (an HTTP or, mixed in first, an HTTPS connection)."""

    def __init__(self, *args, watchdog: _Watchdog, **kwargs):
        super().__init__(*args, **kwargs)
        self._watchdog = watchdog

    def connect(self) -> None:
        super().connect()
        self._watchdog.watch(self.sock)


class _HTTPConnection(_WatchedConnection):
    pass


class _HTTPSConnection(_WatchedConnection, http.client.HTTPSConnection):
    pass


class _WatchedHandler(urllib.request.HTTPHandler, urllib.request.HTTPSHandler):
    """urllib's http and https handlers, opening watched connections."""

    def __init__(self, watchdog: _Watchdog):
        super().__init__()
        self._watchdog = watchdog

    def http_open(self, request):
        return self.do_open(functools.partial(_HTTPConnection, watchdog=self._watchdog), request)

    def https_open(self, request):
        return self.do_open(functools.partial(_HTTPSConnection, watchdog=self._watchdog), request)


class _NoRedirects(urllib.request.HTTPRedirectHandler):
    """Following a redirect would resend the API key to wherever it points."""

    def redirect_request(self, *args, **kwargs):
        return None


def _opener(watchdog: _Watchdog) -> urllib.request.OpenerDirector:
    return urllib.request.build_opener(_WatchedHandler(watchdog), _NoRedirects())


def _names_json_mode(error: urllib.error.HTTPError) -> bool:
    """Whether an error body (its first 4 KB, read within the request's budget) is about JSON mode."""
    with contextlib.suppress(OSError, http.client.HTTPException):
        body = error.read(4096).lower()
        return any(word in body for word in (b"response_format", b"json_object", b"json mode"))
    return False


def _http_failure(error: urllib.error.HTTPError, json_mode_refused: bool = False) -> Exception:
    """Transient for 429 and 5xx (with Retry-After for 429 and 503), else NoAnswer."""
    if error.code == 429 or error.code >= 500:
        retry_after = _retry_after(error.headers) if error.code in (429, 503) else None
        note = "" if retry_after is None else f" (Retry-After {retry_after:g} s)"
        return Transient(f"HTTP {error.code}{note}", retry_after)
    if 300 <= error.code < 400:
        return NoAnswer(
            f"the endpoint redirected the request (HTTP {error.code}); redirects are "
            "not followed: give the final URL as the base URL"
        )
    return NoAnswer(f"endpoint refused the request: HTTP {error.code}", json_mode_refused)


def _retry_after(headers) -> float | None:
    """Retry-After in seconds; an HTTP date is ignored (the back-off applies instead)."""
    value = (headers.get("Retry-After") or "").strip()
    return float(value) if value.isdigit() else None


def _describe(error: Exception) -> str:
    """A reason that quotes nothing the server sent: http.client's errors can (a bad status
    line that echoes the request would carry the API key)."""
    cause = getattr(error, "reason", error)  # URLError wraps the socket's error
    if isinstance(cause, TimeoutError):
        return "timed out"
    if isinstance(error, urllib.error.URLError):
        return f"connection failed ({cause})"
    if isinstance(error, http.client.HTTPException):
        return f"malformed response ({type(error).__name__})"
    return str(error) or type(error).__name__
