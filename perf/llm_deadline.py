"""Worst-case wall time of an LLM parse against an endpoint that drips, versus its bound.

    python perf/llm_deadline.py [--deadline 30] [--drip 0.5]

A local server answers every request with a status line, then one byte every `--drip` seconds,
for ever: in the response body, or in the headers. Each byte resets a socket timeout, so only the
parser's wall-clock limits end the parse; it must fall back to the offline parser by
`LLMConfig.deadline_s` (plus the offline parse, well under a second here).
"""

from __future__ import annotations

import argparse
import dataclasses
import http.server
import threading
import time

from ocplace.models.parsing import LLMConfig, ParsingConfig, make_parser

INSTRUCTION = "put it to the left of the red bowl"  # the offline fallback needs no encoder here
STARTS = {
    "body": b"HTTP/1.0 200 OK\r\nContent-Length: 100000\r\n\r\n{",
    "headers": b"HTTP/1.0 200 OK\r\nX-Slow: ",
}


def drip_server(start: bytes, interval: float, stop: threading.Event) -> http.server.HTTPServer:
    class Drip(http.server.BaseHTTPRequestHandler):
        def do_POST(self):
            try:
                self.wfile.write(start)
                while not stop.wait(interval):
                    self.wfile.write(b"x")
            except OSError:  # the parser hung up: its deadline worked
                pass

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Drip)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True).start()
    return server


def timed_parse(config: LLMConfig, where: str, interval: float) -> tuple[float, str | None]:
    stop = threading.Event()
    server = drip_server(STARTS[where], interval, stop)
    llm = dataclasses.replace(config, base_url=f"http://127.0.0.1:{server.server_port}/v1")
    parser = make_parser("llm", ParsingConfig(llm=llm))
    start = time.perf_counter()
    (item,) = parser.parse(INSTRUCTION)
    seconds = time.perf_counter() - start
    stop.set()
    server.shutdown()
    server.server_close()
    return seconds, item.fallback_reason


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--deadline", type=float, default=LLMConfig().deadline_s)
    parser.add_argument("--drip", type=float, default=0.5, help="seconds between bytes")
    args = parser.parse_args()

    config = LLMConfig(deadline_s=args.deadline, use_cache=False)
    print(
        f"LLMConfig: timeout_s {config.timeout_s:g}, deadline_s {config.deadline_s:g}, "
        f"max_attempts {config.max_attempts}, backoff_s {config.backoff_s:g}"
    )
    worst = 0.0
    for where in STARTS:
        seconds, reason = timed_parse(config, where, args.drip)
        worst = max(worst, seconds)
        print(f"drip in the {where} (1 byte every {args.drip:g} s): {seconds:.2f} s; fallback_reason: {reason}")
    print(
        f"parse against a drip endpoint: {worst:.2f} s worst case; bound {config.deadline_s:g} s "
        f"(deadline_s) + the offline parse"
    )


if __name__ == "__main__":
    main()
