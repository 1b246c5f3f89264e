"""The one progress protocol of the long stages, and its helpers (no torch, no Drake).

A stage reports ``progress(message, done, total)``: ``total > 0`` counts steps
(``0 <= done <= total``), ``total == 0`` is a message without a count (a step
whose length is unknown, or a line for the log). The CLI renders the calls
(:mod:`real2sim.cli.progress`); a library caller passes any callable of this
shape, or nothing (:func:`null_progress`).
"""

from __future__ import annotations

from typing import Protocol


class ProgressFn(Protocol):
    def __call__(self, message: str, done: int, total: int) -> None:
        """``message``: what is being done; ``done`` of ``total`` steps, ``total`` 0 when not counted."""


def null_progress(message: str, done: int, total: int) -> None:
    """Reports nowhere: the default of every stage."""


def prefixed(progress: ProgressFn | None, prefix: str) -> ProgressFn:
    """``progress`` with ``"<prefix>: "`` in front of every message (a sub-stage inside a stage)."""
    report = progress or null_progress

    def inner(message: str, done: int, total: int) -> None:
        report(f"{prefix}: {message}" if message else prefix, done, total)

    return inner


__all__ = ["ProgressFn", "null_progress", "prefixed"]
