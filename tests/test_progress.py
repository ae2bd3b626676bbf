"""Progress of long steps (runtime/progress.py): bars in the command's process, whole lines with the ETA from the
executor's workers, nothing with --no-progress."""

import re

from ocplace.runtime import ExecutorConfig, Task, map_tasks, open_executor
from ocplace.runtime import progress as progress_module
from ocplace.runtime.progress import WORKER_PROGRESS_ENV, progress_bar

LINE = re.compile(r"^counting: +(\d+)%\|.*\| (\d+)/(\d+) \[.*<.*\]")  # desc, share, count, elapsed<ETA


def count_to(total: int) -> int:
    """A task that reports its progress as any long step does."""
    bar = progress_bar(total=total, desc="counting", unit="item")
    for step in range(total):
        bar.update(1)
        bar.set_postfix(step=step)  # redraws a bar at once: a line still waits for its interval
    bar.close()
    return total


def test_a_workers_progress_is_whole_lines_with_the_eta(capfd):
    with open_executor(ExecutorConfig(workers=1)) as executor:
        assert [value for _, value in map_tasks(executor, [Task(count_to, (5,), pinned=True)])] == [5]
    lines = [line for line in capfd.readouterr().out.splitlines() if line.startswith("counting")]
    assert [LINE.match(line).group(2, 3) for line in lines] == [("0", "5"), ("5", "5")]  # its start and its end


def test_no_progress_silences_the_workers(capfd):
    with open_executor(ExecutorConfig(workers=1, progress=False)) as executor:
        assert [value for _, value in map_tasks(executor, [Task(count_to, (5,), pinned=True)])] == [5]
    captured = capfd.readouterr()
    assert "counting" not in captured.out and "counting" not in captured.err


def test_a_line_at_most_every_interval(monkeypatch, capsys):
    monkeypatch.setenv(WORKER_PROGRESS_ENV, "lines")
    monkeypatch.setattr(progress_module, "LINE_INTERVAL_S", 0.0)
    count_to(3)
    every = [LINE.match(line).group(2) for line in capsys.readouterr().out.splitlines()]
    assert every[0] == "0" and every[-1] == "3" and len(every) >= 4
    monkeypatch.setattr(progress_module, "LINE_INTERVAL_S", 3600.0)
    count_to(3)
    assert [LINE.match(line).group(2) for line in capsys.readouterr().out.splitlines()] == ["0", "3"]


def test_the_commands_own_process_draws_a_bar(monkeypatch, capsys):
    monkeypatch.delenv(WORKER_PROGRESS_ENV, raising=False)
    count_to(3)
    captured = capsys.readouterr()
    assert captured.out == "" and "counting" in captured.err  # tqdm's bar, in place on stderr


def test_a_step_that_does_not_move_still_prints_its_clock(monkeypatch, capsys):
    import time

    monkeypatch.setenv(WORKER_PROGRESS_ENV, "lines")
    monkeypatch.setattr(progress_module, "LINE_INTERVAL_S", 0.05)
    bar = progress_bar(total=2, desc="counting", unit="item")
    time.sleep(0.5)  # a long compile: no update at all
    bar.close()
    counts = [LINE.match(line).group(2) for line in capsys.readouterr().out.splitlines()]
    assert counts[0] == "0" and len(counts) >= 3 and set(counts) == {"0"}  # the heartbeat's lines, and no final dup
