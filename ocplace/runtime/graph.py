"""A task graph on an executor: each node runs once every node it depends on has succeeded.

Nodes start as soon as their inputs are done and their CPUs are free, so independent work (the
trainings of several methods, fractions and seeds; their evaluations) runs side by side. A node
that fails is reported and every node that depends on it is skipped; the rest go on.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from ocplace.runtime.executor import Executor, Task


@dataclasses.dataclass(frozen=True)
class Node:
    """`make` builds the task from the results of `after` (by key), when they are all done."""

    key: str
    make: Callable[[Mapping[str, Any]], Task]
    after: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class Outcome:
    key: str
    value: Any = None
    error: BaseException | None = None
    skipped_because: str | None = None  # the key of a failed node this one depended on

    @property
    def ok(self) -> bool:
        return self.error is None and self.skipped_because is None


def _check(nodes: list[Node]) -> None:
    keys = [node.key for node in nodes]
    if len(set(keys)) != len(keys):
        raise ValueError(f"task graph has duplicate keys: {sorted(k for k in keys if keys.count(k) > 1)}")
    seen: set[str] = set()
    for node in nodes:  # dependencies must come first, which also rules out cycles
        missing = [key for key in node.after if key not in seen]
        if missing:
            raise ValueError(f"task {node.key!r} depends on {missing}, which are not listed before it")
        seen.add(node.key)


def run_graph(
    executor: Executor,
    nodes: Iterable[Node],
    on_outcome: Callable[[Outcome], None] = lambda outcome: None,
    on_start: Callable[[str, Task], None] = lambda key, task: None,
) -> dict[str, Outcome]:
    """Runs every node (listed after its dependencies); returns each node's outcome by key.

    A node whose task cannot be built or submitted fails like one whose task raised.
    """
    nodes = list(nodes)
    _check(nodes)
    outcomes: dict[str, Outcome] = {}
    ready: dict[str, Task] = {}  # built once its inputs are done, waiting for free CPUs
    waiting = list(nodes)
    running: dict[Any, tuple[Node, int]] = {}
    used = 0

    def finish(outcome: Outcome) -> None:
        outcomes[outcome.key] = outcome
        on_outcome(outcome)

    while waiting or running:
        for node in list(waiting):
            failed = next((key for key in node.after if key in outcomes and not outcomes[key].ok), None)
            if failed is not None:
                waiting.remove(node)
                finish(Outcome(node.key, skipped_because=failed))
                continue
            if not all(key in outcomes for key in node.after):
                continue
            try:
                task = ready.get(node.key) or node.make({key: outcomes[key].value for key in node.after})
            except Exception as error:
                waiting.remove(node)
                finish(Outcome(node.key, error=error))
                continue
            if running and used + task.cpus > executor.capacity:
                ready[node.key] = task
                continue
            waiting.remove(node)
            ready.pop(node.key, None)
            on_start(node.key, task)
            try:
                handle = executor.submit(task)
            except Exception as error:
                finish(Outcome(node.key, error=error))
                continue
            running[handle] = (node, task.cpus)
            used += task.cpus
        if not running:
            continue
        done, _ = executor.wait(list(running))
        for handle in done:
            node, cpus = running.pop(handle)
            used -= cpus
            try:
                outcome = Outcome(node.key, value=executor.result(handle))
            except Exception as error:
                outcome = Outcome(node.key, error=error)
            finish(outcome)
    return outcomes
