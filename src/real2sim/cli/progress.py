"""The one renderer of the stages' progress (:mod:`real2sim.plumbing.progress`) on stderr.

On a terminal: one rich line, a bar with counts and ETA while steps are counted
(``total > 0``), a spinner and the message otherwise; messages without a count
are also kept as log lines above it. Elsewhere (a pipe, a file, CI): plain lines,
every message without a count, and of counted work its first step, its last,
and one step every few seconds between; each line is written when the next
call comes, so work that stops on bad input leaves only the one-line error.
"""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from typing import Callable, Iterator

from real2sim.plumbing.progress import ProgressFn

#: Plain (non-terminal) output: seconds between two lines of the same counted work.
PLAIN_INTERVAL_S = 5.0


class _Plain:
    """Plain lines on stderr, counted work throttled. Each call is written when the next one comes
    (or the work ends): a stage that fails on bad input leaves only its one-line error."""

    def __init__(self, echo: Callable[[str], None]):
        self.echo = echo
        self.last_line = float("-inf")
        self.counting = ""
        self.pending: tuple[str, int, int] | None = None

    def __call__(self, message: str, done: int, total: int) -> None:
        self.flush(final=False)
        self.pending = (message, done, total)

    def flush(self, final: bool = True) -> None:
        if self.pending is None:
            return
        (message, done, total), self.pending = self.pending, None
        if total <= 0:
            self.echo(message)
            self.counting = ""
            return
        now = time.monotonic()
        if final or message != self.counting or done >= total or now - self.last_line >= PLAIN_INTERVAL_S:
            print(f"{message}: {done}/{total}", file=sys.stderr, flush=True)
            self.last_line, self.counting = now, message


class _Live:
    """One rich line: a bar with ETA for counted steps, a spinner with the message otherwise."""

    def __init__(self, bar, task, echo: Callable[[str], None]):
        self.bar, self.task, self.echo = bar, task, echo

    def __call__(self, message: str, done: int, total: int) -> None:
        if total <= 0:
            self.echo(message)
            self.bar.update(self.task, description=message, completed=0, total=None)
        else:
            self.bar.update(self.task, description=message, completed=min(done, total), total=total)


@contextmanager
def progress_display(echo: Callable[[str], None] | None = None, *, console=None) -> Iterator[ProgressFn]:
    """A :class:`~real2sim.plumbing.progress.ProgressFn` that draws on stderr while the block runs.

    ``echo``: where messages without a count go as lines (default: logged on stderr, above
    the bar on a terminal); ``evaluate`` prints them on stdout, as it always has.
    """
    from rich.console import Console

    console = console or Console(stderr=True, log_path=False)
    if not console.is_terminal:
        plain = _Plain(echo or (lambda message: print(message, file=sys.stderr, flush=True)))
        yield plain  # an exception drops the last call's line: the error says what failed
        plain.flush()
        return
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn,
                               TimeElapsedColumn, TimeRemainingColumn)

    columns = (SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn())
    with Progress(*columns, console=console, transient=True) as bar:
        task = bar.add_task("", total=None)
        yield _Live(bar, task, echo or console.log)


__all__ = ["PLAIN_INTERVAL_S", "progress_display"]
