"""The program, not the stages, chooses torch's CPU threads: `--threads`, else $REAL2SIM_THREADS."""

from __future__ import annotations

import contextlib
import io

import torch

from real2sim.cli import main


def test_threads_option_and_environment_set_torch_threads_once(monkeypatch):
    before = torch.get_num_threads()
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            assert main(["--threads", "1", "objects", "list"]) == 0
            assert torch.get_num_threads() == 1
            monkeypatch.setenv("REAL2SIM_THREADS", "2")
            assert main(["objects", "list"]) == 0
            assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_bad_threads_environment_is_one_line(monkeypatch):
    monkeypatch.setenv("REAL2SIM_THREADS", "many")
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        assert main(["objects", "list"]) == 2
    assert len(err.getvalue().strip().splitlines()) == 1 and "REAL2SIM_THREADS" in err.getvalue()
