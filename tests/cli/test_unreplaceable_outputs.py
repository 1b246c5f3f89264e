"""An output that cannot be replaced is found before the work, not after it; a refused output
leaves nothing behind (issue: the third reliability pass)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from real2sim.plumbing.outputs import MARKER_NAME, replace_blocker
from tests.cli_helpers import run_cli


def chattr(flag: str, path: Path) -> bool:
    if shutil.which("chattr") is None:
        return False
    return subprocess.run(["chattr", flag, str(path)], capture_output=True).returncode == 0


@pytest.fixture()
def immutable(tmp_path):
    """An earlier real2sim output folder made immutable (`chattr +i`), put back afterwards."""
    folder = tmp_path / "earlier"
    folder.mkdir()
    (folder / MARKER_NAME).write_text("{}")
    (folder / "model.urdf").write_text("<robot/>")
    if not chattr("+i", folder):
        pytest.skip("chattr +i is not available on this file system")
    yield folder
    chattr("-i", folder)


def assert_refused_before_work(code: int, err: str, folder: Path) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "cannot be replaced" in err and "immutable" in err, err
    assert not list(folder.parent.glob(f".{folder.name}.tmp-*")), "a temporary folder was left beside it"
    assert (folder / "model.urdf").read_text() == "<robot/>"


@pytest.mark.parametrize("argv", [
    ["asset", "{mesh}", "--mass-kg", "0.4", "--collision", "spheres:4"],
    ["capture", "can", "--views", "12", "--width-px", "96", "--height-px", "72"],
    ["excite", "can", "--mass-kg", "0.4", "--duration-s", "8"],
], ids=lambda a: a[0])
def test_an_immutable_output_is_refused_before_the_work(tmp_path, monkeypatch, capsys, immutable, argv):
    monkeypatch.chdir(tmp_path)
    mesh = tmp_path / "box.obj"
    mesh.write_text("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    argv = [a.replace("{mesh}", str(mesh)) for a in argv]
    code, _, err = run_cli(capsys, *argv, "--out", immutable, "--overwrite")
    assert_refused_before_work(code, err, immutable)


def test_an_immutable_entry_inside_the_output_is_found_too(tmp_path):
    folder = tmp_path / "earlier"
    (folder / "visual").mkdir(parents=True)
    assert replace_blocker(folder) is None
    if not chattr("+i", folder / "visual"):
        pytest.skip("chattr +i is not available on this file system")
    try:
        assert "visual is immutable" in replace_blocker(folder)
    finally:
        chattr("-i", folder / "visual")


def test_board_that_cannot_be_made_leaves_no_folders(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, "board", "--out", "new/deeper/b.pdf", "--board-square-mm", "100")
    assert code == 2 and "does not fit" in err
    assert not (tmp_path / "new").exists()
    (tmp_path / "mine").mkdir()  # a folder that was there before is kept, even empty
    code, _, _ = run_cli(capsys, "board", "--out", "mine/deeper/b.pdf", "--board-square-mm", "100")
    assert code == 2 and (tmp_path / "mine").is_dir() and not (tmp_path / "mine" / "deeper").exists()


def test_board_onto_a_dangling_link_keeps_the_link(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    os.symlink(tmp_path / "nowhere" / "x.pdf", tmp_path / "b.pdf")
    code, _, err = run_cli(capsys, "board", "--out", "b.pdf")
    assert code == 2 and "symbolic link" in err and "does not exist" in err
    assert os.path.islink(tmp_path / "b.pdf") and not (tmp_path / "b.png").exists()


def test_an_output_made_unreplaceable_during_the_work_keeps_the_work(tmp_path):
    from real2sim.plumbing.errors import UserInputError
    from real2sim.plumbing.outputs import atomic_output_dir

    target = tmp_path / "earlier"
    target.mkdir()
    (target / MARKER_NAME).write_text("{}")
    with pytest.raises(UserInputError, match="kept in") as caught:
        with atomic_output_dir(target, overwrite=True) as tmp:
            (tmp / "result.txt").write_text("minutes of work")
            if not chattr("+i", target):
                pytest.skip("chattr +i is not available on this file system")
    try:
        kept = Path(str(caught.value).rsplit("kept in ", 1)[1])
        assert (kept / "result.txt").read_text() == "minutes of work"
    finally:
        chattr("-i", target)
