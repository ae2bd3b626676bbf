"""Where tasks run: this machine's processes or a Ray cluster, behind one interface (`executor.py`)."""

from ocplace.runtime.executor import Executor, ExecutorConfig, Task, map_tasks
from ocplace.runtime.opening import open_executor

__all__ = ["Executor", "ExecutorConfig", "Task", "map_tasks", "open_executor"]
