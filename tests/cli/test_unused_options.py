"""An option that the rest of the command would ignore is refused, naming what it needs, rather than
silently unused (issue: the third reliability pass found these with benchmarks/reliability_pass.py)."""

from __future__ import annotations

import os

import pytest

from tests.cli_helpers import run_cli


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("unused")
    from real2sim.cli import main

    assert main(["capture", "can", "--views", "12", "--width-px", "96", "--height-px", "72", "--out", str(root / "ds")]) == 0
    (root / "weights.pth").write_bytes(b"not weights")
    return root


@pytest.mark.parametrize("argv, words", [
    (["run", "{ds}", "--mass-kg", "0.4", "--tasks", ""], "--tasks is for --evaluate"),
    (["run", "{ds}", "--mass-kg", "0.4", "--contact", "bogus"], "--contact is for --evaluate"),
    (["run", "{ds}", "--mass-kg", "0.4", "--runs", "3"], "--runs is for --evaluate"),
    (["run", "{ds}", "--mass-kg", "0.4", "--mask-weights", "{w}"], "--mask-weights is for --mask maskrcnn"),
    (["mask", "{ds}", "--method", "provided", "--mask-weights", "{w}"], "--mask-weights is for --method maskrcnn"),
    (["evaluate", "{ds}", "--ray-address", "bogus"], "--ray-address is for --executor ray"),
])
def test_an_option_that_would_be_ignored_is_refused(dataset, capsys, argv, words):
    argv = [a.replace("{ds}", str(dataset / "ds")).replace("{w}", str(dataset / "weights.pth")) for a in argv]
    if argv[0] in ("run", "evaluate"):
        argv += ["--out", str(dataset / "out")]
    code, _, err = run_cli(capsys, *argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and words in lines[0], err
    assert not (dataset / "out").exists()


def test_evaluate_refuses_a_link_to_nothing_before_any_work(tmp_path, capsys):
    (tmp_path / "asset").mkdir()
    os.symlink(tmp_path / "nowhere" / "x", tmp_path / "results")
    code, _, err = run_cli(capsys, "evaluate", tmp_path / "asset", "--out", tmp_path / "results")
    assert code == 2 and "symbolic link" in err and not (tmp_path / "nowhere").exists()


def test_evaluate_refuses_an_overlong_name_in_one_line(tmp_path, capsys):
    (tmp_path / "asset").mkdir()
    code, _, err = run_cli(capsys, "evaluate", tmp_path / "asset", "--out", tmp_path / ("n" * 300))
    assert code == 2 and "longer than the file system allows" in err and "internal error" not in err
