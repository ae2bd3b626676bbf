"""The CPU count JAX compiles for, fixed per task so results do not depend on where a task runs.

XLA's CPU client sizes its thread pool to the CPUs the process may use when the client starts, and
splits jitted reductions by that size: the same training gives other bits on a machine (or under a
CPU affinity) with another CPU count. A task therefore starts JAX while the process is pinned to
exactly the CPUs it declared, then lifts the pin from every thread (the client's threads inherit
the pin, and Linux sets affinity per thread), so the OS may run them on any CPU.
"""

from __future__ import annotations

import os
from pathlib import Path

from ocplace.errors import ClusterError


def _started() -> bool:
    import jax._src.xla_bridge as bridge  # no public way to ask without starting a backend

    return bridge.backends_are_initialized()


def pin_jax_width(cpus: int) -> None:
    """Starts JAX's CPU client sized to `cpus` CPUs (all it may use, on a machine with fewer); must run
    before anything else in the process uses JAX."""
    if _started():
        raise ClusterError(
            "JAX already runs in this process, so its CPU count can no longer be fixed; run the task in a "
            "fresh process (Task(fresh_process=True))"
        )
    allowed = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, allowed[:cpus])
    try:
        import jax

        jax.devices("cpu")
    finally:
        for thread in Path("/proc/self/task").iterdir():
            try:
                os.sched_setaffinity(int(thread.name), allowed)
            except ProcessLookupError:  # a thread that ended meanwhile
                pass
