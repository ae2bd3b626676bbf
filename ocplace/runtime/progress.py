"""Progress of a long step, wherever it runs: a tqdm bar drawn in place in the command's own process; whole lines
from a worker process (a local pool's, a Ray actor's), whose output it shares with the other workers and the
command's own step lines, so that nothing is drawn over and nothing is silent for long.

A worker learns which from its environment (`WORKER_PROGRESS_ENV`, set by `init_worker` from the executor's
configuration, `--no-progress` switching it off): the functions that report progress are the same in a worker and
in the foreground, and keep their `progress` argument for the foreground.
"""

from __future__ import annotations

import io
import os
import threading
import time
from typing import Any

from tqdm import tqdm

WORKER_PROGRESS_ENV = "OCPLACE_WORKER_PROGRESS"  # "lines" or "off"; unset in the command's own process
# A worker's bar prints a line at most this often; under the 10 s that a step may stay silent (README's promise).
LINE_INTERVAL_S = 8.0


class LineBar(tqdm):
    """A tqdm bar that prints whole lines (`desc: 40%| 160/400 [01:02<01:33, 2.6scene/s]`): its first, then one per
    `LINE_INTERVAL_S` whether or not it moved (a heartbeat thread: a step that compiles for 30 s still shows its
    clock), never more often (tqdm redraws on every `set_postfix` too), and its last when it ends."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._printed: tuple[float, float] | None = None  # (when, n) of the last line; tqdm's __init__ draws
        self._closing, self._ended, self._line_lock = False, threading.Event(), threading.Lock()
        kwargs |= {"mininterval": LINE_INTERVAL_S, "file": io.StringIO(), "ascii": True, "ncols": 100, "leave": True}
        super().__init__(*args, **kwargs)
        threading.Thread(target=self._heartbeat, args=(max(LINE_INTERVAL_S, 0.05),), daemon=True).start()

    def _heartbeat(self, interval: float) -> None:
        while not self._ended.wait(interval):
            with self._line_lock:  # never a line after close() has begun
                if not self._ended.is_set():
                    self.display()

    def display(self, msg: str | None = None, pos: int | None = None) -> bool:
        if msg == "":  # clears a bar drawn in place: a line printed stays
            return True
        now = time.monotonic()
        if self._closing:
            due = self._printed is None or self._printed[1] != self.n  # the last state, once
        else:
            due = self._printed is None or now - self._printed[0] >= LINE_INTERVAL_S
        if due:
            print(self.format_meter(**self.format_dict).strip(), flush=True)
            self._printed = (now, self.n)
        return True

    def close(self) -> None:
        with self._line_lock:
            self._ended.set()
            self._closing = True
        super().close()


def worker_progress_mode(progress: bool) -> str:
    """The value of `WORKER_PROGRESS_ENV` in a worker of a command run with (or without) progress."""
    return "lines" if progress else "off"


def progress_bar(iterable: Any = None, *, enabled: bool = True, **kwargs: Any) -> tqdm:
    """`tqdm(iterable, **kwargs)`, shown when `enabled`: in place here, as lines in a worker (or nothing, when
    the command was asked for no progress)."""
    mode = os.environ.get(WORKER_PROGRESS_ENV)
    if mode == "lines" and enabled:
        return LineBar(iterable, **kwargs)
    return tqdm(iterable, disable=not enabled or mode == "off", **kwargs)
