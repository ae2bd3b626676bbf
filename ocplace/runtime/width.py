"""The CPU count JAX compiles for, fixed per task so results do not depend on where a task runs.

XLA's CPU client sizes its thread pool to the CPUs the process may use when the client starts, and
splits jitted reductions by that size: the same training gives other bits on a machine (or under a
CPU affinity) with another CPU count. A task therefore starts JAX while the process is pinned to
exactly the CPUs it declared, then lifts the pin from every thread (the client's threads inherit
the pin, and Linux sets affinity per thread), so the OS may run them on any CPU.

Such a task also keeps what XLA compiles in JAX's persistent compilation cache, so a fresh process
does not compile again what an earlier one did. An executable holds the width and the CPU features it
was compiled for, so the cache has one folder per CPU type and width.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import platform
from collections.abc import Iterator
from pathlib import Path

from ocplace.errors import ClusterError
from ocplace.paths import compiled_cache

# Above this size JAX evicts the least recently used executables; with eviction on it also locks the
# folder, which tasks on several processes and nodes write at once.
COMPILED_CACHE_BYTES = 2 << 30
# How wide a training's JAX is unless its experiment says otherwise (`TaskCpus.train`), `ocplace train` included,
# so the same recipe gives the same bits from either command.
TRAIN_CPUS = 2


def _started() -> bool:
    import jax._src.xla_bridge as bridge  # no public way to ask without starting a backend

    return bridge.backends_are_initialized()


def pin_jax_width(cpus: int) -> None:
    """Starts JAX's CPU client sized to `cpus` CPUs (all it may use, on a machine with fewer); must run
    before anything else in the process uses JAX."""
    if _started():
        raise ClusterError(
            "JAX already runs in this process, so its CPU count can no longer be fixed; run the task in a "
            "process of its own (Task(pinned=True))"
        )
    with pinned_cpus(cpus) as width:
        import jax

        jax.config.update("jax_compilation_cache_dir", str(compiled_folder(width)))
        jax.config.update("jax_compilation_cache_max_size", COMPILED_CACHE_BYTES)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.devices("cpu")


@contextlib.contextmanager
def pinned_cpus(cpus: int) -> Iterator[int]:
    """Pins this process to its first `cpus` allowed CPUs inside the block (yields how many that is), then lifts
    the pin from every thread: threads started inside inherit it, and Linux sets affinity per thread."""
    allowed = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, allowed[:cpus])
    try:
        yield min(cpus, len(allowed))
    finally:
        for thread in Path("/proc/self/task").iterdir():
            try:
                os.sched_setaffinity(int(thread.name), allowed)
            except ProcessLookupError:  # a thread that ended meanwhile
                pass


def compiled_folder(width: int) -> Path:
    """The compilation cache of JAX `width` CPUs wide on this machine's CPU type."""
    return compiled_cache() / f"{_cpu_type()}-{width}cpu"


def _cpu_type() -> str:
    """A short hash of the architecture and the first CPU's model and features, which XLA compiles for
    (x86 names them "model name" and "flags", ARM "CPU implementer", "CPU part" and "Features")."""
    lines = Path("/proc/cpuinfo").read_text().splitlines()
    keys = ("model name", "flags", "cpu implementer", "cpu part", "features")
    described: dict[str, str] = {}
    for line in lines:
        if line.lower().startswith(keys):
            described.setdefault(line.split(":")[0].strip().lower(), line)
    record = [platform.machine(), *(described.get(key, "") for key in keys)]
    return hashlib.sha256("\n".join(record).encode()).hexdigest()[:12]
