import pytest

from real2sim.formats.errors import UserInputError
from real2sim.formats.outputs import atomic_output_dir


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
    from real2sim.formats.outputs import check_output_dir

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
    from real2sim.formats.outputs import output_lock

    target = tmp_path / "out"
    with output_lock(target):
        with output_lock(target):
            assert (tmp_path / ".out.lock").exists()
        assert (tmp_path / ".out.lock").exists()
    assert not (tmp_path / ".out.lock").exists()


def test_publish_refuses_a_foreign_folder_that_appeared_meanwhile(tmp_path):
    from real2sim.formats.outputs import publish_dir

    finished = tmp_path / ".out.tmp-1"
    finished.mkdir()
    (finished / "a.txt").write_text("new")
    target = tmp_path / "out"
    target.mkdir()
    (target / "theirs.txt").write_text("keep")
    with pytest.raises(UserInputError, match="kept in"):
        publish_dir(finished, target)
    assert (target / "theirs.txt").read_text() == "keep" and (finished / "a.txt").exists()
