"""A recording :class:`real2sim.plumbing.progress.ProgressFn` for the stages' tests."""

from __future__ import annotations


class Recorder:
    """Records every ``progress(message, done, total)`` call of a stage."""

    def __init__(self) -> None:
        self.events: list[tuple[str, int, int]] = []

    def __call__(self, message: str, done: int, total: int) -> None:
        self.events.append((message, done, total))

    def check(self, counted: bool = True) -> list[tuple[str, int, int]]:
        """Assert every call had the protocol's shape: (str, int, int), 0 <= done <= total or
        total == 0; with ``counted``, at least one counted step. Returns the events."""
        assert self.events, "the stage reported no progress"
        for event in self.events:
            message, done, total = event
            assert isinstance(message, str) and message, event
            assert type(done) is int and type(total) is int, event
            assert total == 0 or 0 <= done <= total, event
            assert total >= 0, event
        if counted:
            assert any(total > 0 for _, _, total in self.events), self.events
        return self.events
