"""The CLI's one progress renderer (real2sim.cli.progress): plain lines off a terminal, rich on one."""

from __future__ import annotations

import contextlib
import io

from rich.console import Console

from real2sim.cli import progress as cli_progress
from real2sim.cli.progress import progress_display


def test_plain_lines_when_stderr_is_not_a_terminal(monkeypatch):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), progress_display() as progress:
        progress("visual hull", 0, 0)
        for done in range(1, 101):
            progress("training field (8x8x8)", done, 100)
        progress("texture", 0, 0)
    lines = err.getvalue().splitlines()
    # The messages, the counted work's first and last step (every few seconds between): no flood.
    assert lines == ["visual hull", "training field (8x8x8): 1/100", "training field (8x8x8): 100/100", "texture"]


def test_messages_can_go_elsewhere():
    seen: list[str] = []
    err = io.StringIO()
    with contextlib.redirect_stderr(err), progress_display(echo=seen.append) as progress:
        progress("3 simulations to run, 0 already done", 0, 0)
        progress("references and simulations", 3, 3)
    assert seen == ["3 simulations to run, 0 already done"]
    assert err.getvalue().splitlines() == ["references and simulations: 3/3"]


def test_terminal_shows_a_bar_and_logs_the_messages():
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=100, log_path=False, log_time=False)
    with progress_display(console=console) as progress:
        progress("asset: estimating inertia", 0, 0)
        progress("fit", 50, 100)
    text = out.getvalue()
    assert "asset: estimating inertia" in text and "fit" in text
    assert cli_progress.PLAIN_INTERVAL_S > 0
