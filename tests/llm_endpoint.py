"""Replies of the OpenAI-compatible endpoints that tests serve on 127.0.0.1 with `http.server`."""

from __future__ import annotations

import json


def completion(content: str) -> bytes:
    """A chat-completion body whose one message is `content`."""
    return json.dumps({"choices": [{"message": {"role": "assistant", "content": content}}]}).encode()


def send(handler, status: int, body: bytes, headers=(), announce_length: bool = True, message=None) -> None:
    """Writes a whole response from a `BaseHTTPRequestHandler`."""
    handler.send_response(status, message)
    for name, value in headers:
        handler.send_header(name, value)
    if announce_length:
        handler.send_header("Content-Length", str(len(body)))
    handler.end_headers()
    handler.wfile.write(body)
