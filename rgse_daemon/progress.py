"""Progress bars for long CLI commands: a rich display on stderr when stderr is an interactive terminal, nothing
otherwise (pipes, files and CI logs get no escape codes). stdout is never touched: it stays the command's output and
``--json`` stays one object.

Computations report through a plain :data:`ProgressFn` ``(stage, done, total)``, once per loop or combination (never
per sample); :func:`stage_progress` turns each stage into a bar, or gives None off a terminal. rich is imported only
when a terminal is there to draw on.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import IO, TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console
    from rich.progress import Progress, ProgressColumn, TaskID

#: A progress reporter: ``stage`` names the work (the bar's description), ``done`` of ``total`` items are finished.
ProgressFn = Callable[[str, int, int], None]

#: Redraws per second: each holds the interpreter lock for ~1–2 ms, taken from the computation the bar follows.
REFRESH_PER_S = 4.0


def terminal_console(stream: IO[str] | None = None) -> Console | None:
    """A rich Console on ``stream`` (default: stderr) if it is an interactive terminal, else None.

    The stream itself must be a TTY: FORCE_COLOR or TTY_COMPATIBLE in a CI environment do not turn a log file into
    a terminal here. A dumb terminal (TERM=dumb) or TTY_INTERACTIVE=0 gets no bars either.
    """
    stream = sys.stderr if stream is None else stream
    try:
        if not stream.isatty():
            return None
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return None
    from rich.console import Console

    console = Console(file=stream)
    return console if console.is_interactive else None


def new_progress(console: Console, *extra: ProgressColumn) -> Progress:
    """The standard bar on ``console``: description, bar, done/total, percent, elapsed time, then ``extra`` columns.

    stdout is not redirected through the display: the command's output goes where it always goes.
    """
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TaskProgressColumn,
        TextColumn,
        TimeElapsedColumn,
    )

    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TaskProgressColumn(),
                    TimeElapsedColumn(), *extra, console=console, redirect_stdout=False,
                    refresh_per_second=REFRESH_PER_S)


class StageBars:
    """A :data:`ProgressFn` drawing one bar per stage on a rich Progress (a stage's first report adds its bar)."""

    def __init__(self, progress: Progress) -> None:
        self.progress = progress
        self._tasks: dict[str, TaskID] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        task = self._tasks.get(stage)
        if task is None:
            task = self._tasks[stage] = self.progress.add_task(stage, total=total)
        self.progress.update(task, completed=done, total=total)


@contextmanager
def running(progress: Progress) -> Iterator[Progress]:
    """Show ``progress`` for the duration of the block. Meanwhile whatever goes to stderr, the log lines of the root
    logger's handlers on the terminal included, is printed above the bars instead of through them."""
    with progress:
        terminal = progress.console.file
        moved = [h for h in logging.getLogger().handlers
                 if type(h) is logging.StreamHandler and h.stream is terminal and sys.stderr is not terminal]
        for handler in moved:
            handler.setStream(sys.stderr)  # rich's proxy of the terminal while the bars are shown
        try:
            yield progress
        finally:
            for handler in moved:
                handler.setStream(terminal)


@contextmanager
def stage_progress(stream: IO[str] | None = None) -> Iterator[ProgressFn | None]:
    """Bars on the terminal for the duration of the block: yields a :data:`ProgressFn`, or None (report nothing)
    when ``stream`` (default: stderr) is not an interactive terminal."""
    console = terminal_console(stream)
    if console is None:
        yield None
        return
    with running(new_progress(console)) as progress:
        yield StageBars(progress)
