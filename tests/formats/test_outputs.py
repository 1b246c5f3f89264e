import os
from pathlib import Path

import pytest

from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import atomic_output_dir, check_output_path


def test_success_moves_folder_into_place(tmp_path):
    target = tmp_path / "out"
    with atomic_output_dir(target) as tmp:
        (tmp / "a.txt").write_text("x")
        assert not target.exists()
    assert (target / "a.txt").read_text() == "x"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_failure_leaves_nothing(tmp_path):
    target = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with atomic_output_dir(target) as tmp:
            (tmp / "a.txt").write_text("x")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_existing_folder_needs_overwrite(tmp_path):
    target = tmp_path / "out"
    with atomic_output_dir(target) as tmp:
        (tmp / "old.txt").write_text("old")
    with pytest.raises(UserInputError):
        with atomic_output_dir(target):
            pass
    with atomic_output_dir(target, overwrite=True) as tmp:
        (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in target.iterdir()) == [".real2sim", "new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_overwrite_refuses_inputs_cwd_and_foreign_folders(tmp_path, monkeypatch):
    from real2sim.plumbing.outputs import check_output_dir

    data = tmp_path / "data"
    (data / "sub").mkdir(parents=True)
    (data / "mesh.obj").write_text("x")
    monkeypatch.chdir(data / "sub")
    for target, inputs, words in [
        (data / "sub", [], "working folder"),
        (data, [], "working folder"),
        (tmp_path / "out", [tmp_path / "out"], "is the input"),
        (data, [data / "mesh.obj"], "working folder"),
        (tmp_path / "elsewhere" / "x", [tmp_path / "elsewhere"], "lies inside the input"),
    ]:
        with pytest.raises(UserInputError, match=words):
            check_output_dir(target, overwrite=True, inputs=inputs)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UserInputError, match="contains the input"):
        check_output_dir(data, overwrite=True, inputs=[data / "mesh.obj"])
    with pytest.raises(UserInputError, match="did not make"):
        check_output_dir(data, overwrite=True)
    (tmp_path / "empty").mkdir()
    assert check_output_dir(tmp_path / "empty", overwrite=True) == (tmp_path / "empty").resolve()


def test_lock_is_reentrant_in_a_process_and_removed_after(tmp_path):
    from real2sim.plumbing.outputs import output_lock

    target = tmp_path / "out"
    with output_lock(target):
        with output_lock(target):
            assert (tmp_path / ".out.lock").exists()
        assert (tmp_path / ".out.lock").exists()
    assert not (tmp_path / ".out.lock").exists()


def test_publish_refuses_a_foreign_folder_that_appeared_meanwhile(tmp_path):
    from real2sim.plumbing.outputs import publish_dir

    finished = tmp_path / ".out.tmp-1"
    finished.mkdir()
    (finished / "a.txt").write_text("new")
    target = tmp_path / "out"
    target.mkdir()
    (target / "theirs.txt").write_text("keep")
    with pytest.raises(UserInputError, match="kept in"):
        publish_dir(finished, target)
    assert (target / "theirs.txt").read_text() == "keep" and (finished / "a.txt").exists()


# ------------------------------------------------------------------------- issue 33: paths that cannot be written


def _nothing_can_be_made_in(folder: Path) -> bool:
    try:
        (folder / "real2sim-test-probe").mkdir()
    except OSError:
        return True
    (folder / "real2sim-test-probe").rmdir()
    return False


@pytest.mark.skipif(not Path("/proc").is_dir() or not _nothing_can_be_made_in(Path("/proc")), reason="needs /proc")
def test_output_under_proc_is_refused_up_front():
    """Issue 33 #7: root "may write" /proc by os.access, so the check passed and the lock failed later
    with an internal FileNotFoundError; the check now tries to make something there."""
    from real2sim.plumbing.outputs import check_output_dir, output_lock

    with pytest.raises(UserInputError, match=r"cannot write in /proc"):
        check_output_path("/proc/real2sim-out")
    with pytest.raises(UserInputError, match=r"cannot write in /proc"):
        check_output_dir("/proc/real2sim-out", overwrite=False)
    with pytest.raises(UserInputError, match="cannot write /proc/real2sim-out"):
        with output_lock("/proc/real2sim-out"):
            pass


def test_probe_leaves_nothing_and_empty_path_is_refused(tmp_path):
    assert check_output_path(tmp_path / "out") == tmp_path / "out"
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(UserInputError, match="path is empty"):
        check_output_path("")


def test_symbolic_link_loop_is_named(tmp_path):
    """Issue 33 #10: a link loop was "not found" (or an internal RuntimeError from Path.resolve)."""
    from real2sim.plumbing.outputs import check_output_dir, output_lock
    from real2sim.plumbing.paths import missing

    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    (tmp_path / "file").write_text("x")
    assert "symbolic link loop" in missing(tmp_path / "a", "dataset")
    assert "which does not exist" in missing(tmp_path / "dangling", "dataset")
    assert "a file stands where a folder is" in missing(tmp_path / "file" / "x", "dataset")
    assert missing(tmp_path / "nothing", "dataset") == f"dataset not found: {tmp_path / 'nothing'}"
    with pytest.raises(UserInputError, match="symbolic link loop"):
        check_output_dir(tmp_path / "a" / "out", overwrite=False)
    with pytest.raises(UserInputError, match="symbolic link loop"):
        check_output_dir(tmp_path / "out", overwrite=False, inputs=[tmp_path / "a"])
    with pytest.raises(UserInputError, match="symbolic link loop"):
        with output_lock(tmp_path / "a", inside=True):
            pass


def test_check_replaceable(tmp_path):
    """Issue 33 #7: refine-poses did all its work before finding that transforms.json could not be replaced."""
    import subprocess

    from real2sim.plumbing.outputs import check_replaceable

    target = tmp_path / "transforms.json"
    check_replaceable(target)  # not there yet: fine
    target.write_text("{}")
    check_replaceable(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["transforms.json"] and target.read_text() == "{}"
    if os.geteuid() == 0:  # root ignores permission bits; an immutable file stops even root
        if subprocess.run(["chattr", "+i", str(target)], capture_output=True).returncode != 0:
            pytest.skip("chattr +i not available here")
    else:
        target.chmod(0o444)
    try:
        with pytest.raises(UserInputError, match="cannot be replaced"):
            check_replaceable(target)
    finally:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(target)], check=True)
        target.chmod(0o644)


def test_public_paths_name_the_output_not_a_removed_temporary(tmp_path):
    """Issue 33 #10: a failed write named `.out.tmp-abcd1234/mesh.obj`, a folder removed on the way out."""
    from real2sim.plumbing.temporary_names import public_paths

    gone = f"{tmp_path}/.model.tmp-k2j4_x9q/mesh.obj"
    assert public_paths(f"cannot write {gone}: no space") == f"cannot write {tmp_path}/model/mesh.obj: no space"
    assert public_paths(f"'{tmp_path}/.transforms.json.tmp-ab12cd34.json' -> 'x'") == \
        f"'{tmp_path}/transforms.json' -> 'x'"
    kept = tmp_path / ".asset.tmp-zz99yy88"
    kept.mkdir()
    text = f"the finished result is kept in {kept}"
    assert public_paths(text) == text  # one kept on purpose still exists and is named as it is
    assert public_paths("nothing temporary here") == "nothing temporary here"
