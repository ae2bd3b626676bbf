"""Replies of the OpenAI-compatible endpoints that tests serve on 127.0.0.1 with `http.server`."""

from __future__ import annotations

import contextlib
import http.server
import json
import threading


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


class _FixedAnswer(http.server.BaseHTTPRequestHandler):
    """Answers every request with `server.answer`: an HTTP status, or the text of a completion."""

    def do_POST(self):
        self.rfile.read(int(self.headers["Content-Length"]))
        if isinstance(self.server.answer, int):
            self.send_error(self.server.answer)
            return
        send(self, 200, completion(self.server.answer), [("Content-Type", "application/json")])

    def log_message(self, *args):
        pass


@contextlib.contextmanager
def fixed_answer(answer: int | str):
    """An endpoint on 127.0.0.1 giving `answer` to every request (set `server.answer` to change it)."""
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _FixedAnswer)
    httpd.answer = answer
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    try:
        yield httpd
    finally:
        httpd.shutdown()
        httpd.server_close()


def llm_parser(httpd, offline):
    """An LLM parser asking `httpd` once per instruction, with no answer cache, falling back to `offline`."""
    from ocplace.models.parsing.config import LLMConfig
    from ocplace.models.parsing.llm import LLMParser

    config = LLMConfig(f"http://127.0.0.1:{httpd.server_port}/v1", "canned", max_attempts=1, use_cache=False)
    return LLMParser(config, offline, lambda: offline.snapper)
