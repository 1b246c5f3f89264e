"""Nothing a user owns is destroyed or corrupted (issue: reliability).

Each test is a case that once lost data: `--overwrite` aimed at the working folder or at
an input, an export overwriting another object's texture, a truncated mesh after a full
disk, unreadable output permissions, two writers of one output, SIGTERM leaving a
temporary folder behind.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from real2sim.cli import main
from real2sim.plumbing.outputs import MARKER_NAME
from tests.cli_helpers import run_cli




def assert_refused(code: int, err: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture()
def workdir(tmp_path, monkeypatch) -> Path:
    """A user's folder holding their own mesh and notes; the working folder of the test."""
    folder = tmp_path / "work"
    folder.mkdir()
    (folder / "box.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    (folder / "notes.txt").write_text("mine")
    monkeypatch.chdir(folder)
    return folder


def test_overwrite_never_removes_the_working_folder(workdir, capsys):
    before = snapshot(workdir)
    code, _, err = run_cli(capsys, "asset", "box.obj", "--mass-kg", "1", "--out", ".", "--overwrite")
    assert_refused(code, err)
    assert "working folder" in err
    assert snapshot(workdir) == before


def test_overwrite_never_removes_a_folder_holding_the_input(workdir, capsys):
    data = workdir / "data"
    data.mkdir()
    (data / "box.obj").write_bytes((workdir / "box.obj").read_bytes())
    before = snapshot(workdir)
    code, _, err = run_cli(capsys, "asset", data / "box.obj", "--mass-kg", "1", "--out", data, "--overwrite")
    assert_refused(code, err)
    assert "input" in err
    assert snapshot(workdir) == before


def test_overwrite_never_removes_a_folder_real2sim_did_not_make(workdir, capsys):
    theirs = workdir / "thesis"
    theirs.mkdir()
    (theirs / "chapter1.tex").write_text("precious")
    code, _, err = run_cli(capsys, "asset", "box.obj", "--mass-kg", "1", "--out", theirs, "--overwrite")
    assert_refused(code, err)
    assert MARKER_NAME in err
    assert (theirs / "chapter1.tex").read_text() == "precious"


def test_export_does_not_overwrite_another_objects_texture(workdir, capsys):
    assert run_cli(capsys, "objects", "export", "bottle", "bottle.obj")[0] == 0
    bottle_files = snapshot(workdir)
    assert run_cli(capsys, "objects", "export", "can", "other.obj")[0] == 0
    after = snapshot(workdir)
    assert {k: after[k] for k in bottle_files} == bottle_files  # the bottle's texture and MTL are intact
    assert any(name.startswith("other_") and name.endswith(".png") for name in after)
    # Exporting again over an existing OBJ's files needs --overwrite, and leaves them alone without it.
    code, _, err = run_cli(capsys, "objects", "export", "can", "bottle.obj")
    assert_refused(code, err)
    assert snapshot(workdir) == after


def test_full_disk_during_export_leaves_no_truncated_mesh(workdir):
    # RLIMIT_FSIZE makes a write past 64 KiB fail with EFBIG, as a full disk would (ENOSPC).
    code = textwrap.dedent("""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, 64 * 1024))
        from real2sim.cli import main
        sys.exit(main(["objects", "export", "bottle", "big.obj"]))
    """)
    done = subprocess.run([sys.executable, "-c", code], cwd=workdir, capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "space" in done.stderr or "too large" in done.stderr
    assert not (workdir / "big.obj").exists()
    assert sorted(p.name for p in workdir.iterdir()) in (
        ["box.obj", "notes.txt"],
        # the small texture and MTL fit under the limit and are complete files
        ["big.mtl", "big_material_0.png", "box.obj", "notes.txt"],
    )


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_outputs_follow_the_umask(tmp_path, umask):
    from real2sim.formats.dataset import write_json_atomic
    from real2sim.plumbing.outputs import atomic_output_dir

    previous = os.umask(umask)
    try:
        with atomic_output_dir(tmp_path / "out") as tmp:
            write_json_atomic(tmp / "transforms.json", {"frames": []})
            (tmp / "images").mkdir()
    finally:
        os.umask(previous)
    out = tmp_path / "out"
    assert out.stat().st_mode & 0o777 == 0o777 & ~umask
    assert (out / "images").stat().st_mode & 0o777 == 0o777 & ~umask
    assert (out / "transforms.json").stat().st_mode & 0o777 == 0o666 & ~umask


def test_second_writer_of_one_output_is_refused(workdir, capsys):
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys\nfrom real2sim.plumbing.outputs import output_lock\n"
         "with output_lock(sys.argv[1]):\n    print('held', flush=True)\n    sys.stdin.read()\n",
         str(workdir / "asset")],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        code, _, err = run_cli(capsys, "asset", "box.obj", "--mass-kg", "1", "--out", workdir / "asset")
        assert_refused(code, err)
        assert "another real2sim process" in err
    finally:
        holder.communicate("", timeout=30)
    assert not (workdir / "asset").exists()
    assert not list(workdir.glob(".*lock"))  # the holder removed its lock file


def test_output_path_mistakes_are_one_line(workdir, capsys):
    code, _, err = run_cli(capsys, "asset", "box.obj", "--mass-kg", "1", "--out", workdir / "notes.txt" / "asset")
    assert_refused(code, err)
    assert "is a file" in err
    code, _, err = run_cli(capsys, "asset", "box.obj", "--mass-kg", "1", "--out", workdir / ("x" * 300))
    assert_refused(code, err)
    assert "longer than" in err
    code, _, err = run_cli(capsys, "objects", "export", "can", workdir / "notes.txt" / "can.obj")
    assert_refused(code, err)


def test_unwritable_parent_is_one_line(capsys):
    """Run as an unprivileged user: root may write anywhere, so as root the CLI runs as `nobody`."""
    import shutil
    import tempfile

    base = Path(tempfile.mkdtemp(prefix="real2sim-perm-"))
    try:
        base.chmod(0o755)
        (base / "box.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
        (base / "box.obj").chmod(0o644)
        locked = base / "locked"
        locked.mkdir(mode=0o555)
        locked.chmod(0o555)
        argv = ["asset", str(base / "box.obj"), "--mass-kg", "1", "--out", str(locked / "asset")]
        if os.geteuid() != 0:
            code, _, err = run_cli(capsys, *argv)
        else:
            try:
                done = subprocess.run([sys.executable, "-m", "real2sim", *argv], cwd=base, user=65534,
                                      capture_output=True, text=True, timeout=120)
            except PermissionError:
                pytest.skip("running as root, and the user `nobody` cannot run this Python installation")
            if "real2sim" not in done.stderr:
                pytest.skip(f"the user `nobody` cannot run this Python installation: {done.stderr[-200:]}")
            code, err = done.returncode, done.stderr
        assert_refused(code, err)
        assert "cannot write" in err
        assert list(locked.iterdir()) == []
    finally:
        shutil.rmtree(base, ignore_errors=True)


def test_internal_error_is_one_line_and_debug_shows_the_traceback(monkeypatch, capsys):
    import real2sim.cli.objects as objects_verb

    def broken(args):
        raise ZeroDivisionError("a bug, not a user mistake")

    monkeypatch.setattr(objects_verb, "run", broken)
    code, _, err = run_cli(capsys, "objects")
    assert code == 1 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "internal error" in err and "--debug" in err
    with pytest.raises(ZeroDivisionError):
        main(["--debug", "objects"])


def test_sigterm_during_capture_leaves_no_temporary_folder(tmp_path):
    out = tmp_path / "dataset"
    proc = subprocess.Popen([sys.executable, "-m", "real2sim", "capture", "can", "--out", str(out),
                             "--views", "200", "--width-px", "64", "--height-px", "48"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    # Wait until rendering has begun (the temporary dataset has images), then terminate.
    while time.monotonic() < deadline and proc.poll() is None:
        if any(True for p in tmp_path.glob(".dataset.tmp-*/images/*.png")):
            break
        time.sleep(0.1)
    assert proc.poll() is None, "capture finished before it could be terminated"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------
# `mask` (issue 33 item 2): masks_<method>/ is replaced only when `mask` made it and holds nothing else


@pytest.fixture(scope="module")
def background_ds(tmp_path_factory) -> Path:
    """A tiny capture with the empty scene for --method background (8 views at 64x48, about 2 s)."""
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.geometry.objects import make_textured_object

    out = tmp_path_factory.mktemp("mask_ds") / "ds"
    capture(make_textured_object("can"), out, CaptureConfig(views=8, width=64, height=48, with_background=True))
    return out


@pytest.fixture()
def dataset(background_ds, tmp_path) -> Path:
    import shutil

    copy = tmp_path / "ds"
    shutil.copytree(background_ds, copy)
    return copy


@pytest.mark.parametrize("method", ["background", "parallax"])
def test_mask_never_replaces_a_folder_it_did_not_make(dataset, capsys, method):
    theirs = dataset / f"masks_{method}"
    theirs.mkdir()
    (theirs / "README_MINE.txt").write_text("mine")
    transforms = (dataset / "transforms.json").read_bytes()
    code, _, err = run_cli(capsys, "mask", dataset, "--method", method)
    assert_refused(code, err)
    assert MARKER_NAME in err and "never replaced" in err
    assert snapshot(theirs) == {"README_MINE.txt": b"mine"}
    assert (dataset / "transforms.json").read_bytes() == transforms


def test_mask_rerun_keeps_files_it_did_not_write(dataset, capsys):
    assert run_cli(capsys, "mask", dataset, "--method", "background")[0] == 0
    ours = dataset / "masks_background"
    assert (ours / MARKER_NAME).is_file()
    (ours / "README_MINE.txt").write_text("mine")
    for extra in ([], ["--overwrite"]):  # files mask did not write: never deleted, --overwrite or not
        code, _, err = run_cli(capsys, "mask", dataset, "--method", "background", *extra)
        assert_refused(code, err)
        assert "README_MINE.txt" in err
        assert (ours / "README_MINE.txt").read_text() == "mine"
    (ours / "README_MINE.txt").unlink()
    # a mask edited by hand is the user's work too: replaced only with --overwrite
    first, second = sorted(ours.glob("*.png"))[:2]
    first.write_bytes(second.read_bytes())
    edited = first.read_bytes()
    code, _, err = run_cli(capsys, "mask", dataset, "--method", "background", "--background-threshold", "20")
    assert_refused(code, err)
    assert first.name in err and "--overwrite" in err and first.read_bytes() == edited
    code, _, err = run_cli(capsys, "mask", dataset, "--method", "background", "--background-threshold", "20", "--overwrite")
    assert code == 0, err
    assert first.read_bytes() != edited and not (ours / "README_MINE.txt").exists()
    # nothing but its own masks, as written: a plain rerun replaces the folder
    assert run_cli(capsys, "mask", dataset, "--method", "background")[0] == 0


def test_mask_replaces_its_own_folder_from_before_the_marker(dataset, capsys):
    """A masks_<method>/ that holds only the masks the frames point to was made by an older `mask`."""
    assert run_cli(capsys, "mask", dataset, "--method", "background")[0] == 0
    (dataset / "masks_background" / MARKER_NAME).unlink()
    assert run_cli(capsys, "mask", dataset, "--method", "background")[0] == 0
    assert (dataset / "masks_background" / MARKER_NAME).is_file()


def test_run_masks_a_copy_whatever_masks_folder_the_dataset_has(dataset, tmp_path, capsys):
    """`run --mask background` masks its private copy: a user's masks_background/ in the dataset is
    neither a reason to refuse nor touched."""
    theirs = dataset / "masks_background"
    theirs.mkdir()
    (theirs / "README_MINE.txt").write_text("mine")
    code, _, err = run_cli(capsys, "run", dataset, "--mass-kg", "0.35", "--out", tmp_path / "A", "--mask", "background",
                           "--backend", "hull", "--voxels", "32", "--max-faces", "1000", "--texture-px", "64",
                           "--collision", "mesh", "--no-refine-poses")
    assert code == 0, err
    assert snapshot(theirs) == {"README_MINE.txt": b"mine"}
