"""Validation at the edge (issue #14): every bad value on the command line, or in a dataset, is exit
status 2 and ONE line on stderr naming the option or file, with no traceback and nothing written.

The numeric options are read from the real parser (``real2sim.cli.build_parser()``): each one's
range comes from its type (:class:`real2sim.cli.options.Number`), and hypothesis generates values
outside it (below, above, non-finite, empty, not a number, non-integral, huge). Everything here
fails while arguments are parsed or at an up-front check, so the whole module takes seconds.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import json
import math
import os
import tempfile
from pathlib import Path

import pytest
import trimesh
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from PIL import Image

from real2sim.cli import build_parser, main
from real2sim.cli.options import Number, numeric_actions

from tests.formats.test_dataset import _make_dataset

@functools.lru_cache(maxsize=1)
def verb_parsers() -> dict[str, argparse.ArgumentParser]:
    """Each verb's parser (read only: the tests parse through ``main``, which builds its own)."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def numeric_options() -> list[tuple[str, argparse.Action]]:
    return [(verb, action) for verb, p in verb_parsers().items() for action in numeric_actions(p)]


def range_of(verb: str, action: argparse.Action) -> Number | None:
    return action.type if isinstance(action.type, Number) else None


def _valid_text(t: Number) -> str:
    lo = t.min_value if math.isfinite(t.min_value) else 0.0
    if not t.contains(lo):
        lo = lo + 1 if t.integer else math.nextafter(lo, math.inf)
    return str(int(lo)) if t.integer else repr(float(lo))


def base_argv(verb: str, p: argparse.ArgumentParser, skip: argparse.Action) -> list[str]:
    """The verb with placeholder positionals and valid values for the other required options."""
    argv = [verb]
    for action in p._actions:
        if action is skip or isinstance(action, argparse._HelpAction):
            continue
        if not action.option_strings:
            if action.nargs not in ("?", "*"):
                argv.append(action.choices[0] if action.choices else f"placeholder_{action.dest}")
        elif action.required:
            if action.choices:
                value = next(iter(action.choices))
            elif isinstance(action.type, Number):
                value = _valid_text(action.type)
            else:
                value = f"placeholder_{action.dest}"
            argv += [action.option_strings[-1], value]
    return argv


def run_in(folder: Path, argv: list[str]) -> tuple[int, str]:
    """``main(argv)`` in-process with ``folder`` as the working folder: (exit code, stderr)."""
    err = io.StringIO()
    with contextlib.chdir(folder), contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:
            code = exc.code
    return code, err.getvalue()


def assert_one_line(code: int, err: str, *names: str) -> str:
    assert code == 2, (code, err)
    assert "Traceback" not in err, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].strip(), err
    assert any(n in lines[0] for n in names), (names, err)
    return lines[0]


# ------------------------------------------------------------------------------- every numeric option


def test_every_numeric_option_has_a_range_type():
    """A new `type=int` / `type=float` option (or a numeric default without a type) fails here:
    use a range type from real2sim.cli.options."""
    bare = [f"{verb} {a.option_strings[-1]}" for verb, a in numeric_options()
            if not isinstance(a.type, Number)]
    assert not bare, f"numeric options without a range type (real2sim.cli.options): {bare}"
    assert {v for v, _ in numeric_options()} >= {"demo", "capture", "refine-poses", "mask", "reconstruct", "asset",
                                                 "run", "evaluate", "view"}


def _cases():
    cases = []
    for verb, action in numeric_options():
        option = action.option_strings[-1]
        cases.append(pytest.param(verb, option, id=f"{verb} {option}"))
    return cases


NOT_NUMBERS = ["", " ", "nan", "NaN", "inf", "-inf", "+inf", "infinity", "abc", "1,5", "0x10", "1e", "--", "½", "1 2"]


def bad_values(t: Number) -> st.SearchStrategy[str]:
    """Texts that ``t`` must refuse."""
    options = [st.sampled_from(NOT_NUMBERS)]
    lo, hi = t.min_value, t.max_value
    if t.integer:
        if math.isfinite(lo):
            options.append(st.integers(max_value=int(lo) - 1).filter(lambda v: v not in t.also).map(str))
        if math.isfinite(hi):
            options.append(st.integers(min_value=int(hi) + 1).map(str))
            options.append(st.sampled_from([str(10**30), "9" * 5000]))  # past the int digit limit too
        options.append(st.floats(min_value=max(lo, -1e6), max_value=min(hi, 1e6), allow_nan=False)
                       .filter(lambda v: not float(v).is_integer()).map(repr))  # "2.5" is not an integer
    else:
        if math.isfinite(lo):
            options.append(st.floats(max_value=lo, exclude_max=t.min_inclusive, allow_nan=False,
                                     allow_infinity=False).map(repr))
        if math.isfinite(hi):
            options.append(st.floats(min_value=hi, exclude_min=t.max_inclusive, allow_nan=False,
                                     allow_infinity=False).map(repr))
            options.append(st.sampled_from(["1e999", "9" * 400]))
    return st.one_of(options)


@pytest.mark.parametrize("verb, option", _cases())
@settings(max_examples=20, deadline=None, database=None, derandomize=True,
          phases=(Phase.explicit, Phase.generate), suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_bad_number_is_one_line_exit_2_nothing_written(verb, option, data):
    p = verb_parsers()[verb]
    action = next(a for a in p._actions if option in a.option_strings)
    t = range_of(verb, action)
    assert t is not None, f"{verb} {option}: no range type"
    value = data.draw(bad_values(t), label="value")
    assert not _accepts(t, value), value
    with tempfile.TemporaryDirectory() as folder:
        code, err = run_in(Path(folder), [*base_argv(verb, p, action), f"{option}={value}"])
        assert_one_line(code, err, *action.option_strings)
        assert os.listdir(folder) == [], "nothing may be written"


def _accepts(t: Number, text: str) -> bool:
    try:
        t(text)
    except argparse.ArgumentTypeError:
        return False
    return True


@pytest.mark.parametrize("verb, option", [c.values for c in _cases() if not c.marks])
@settings(max_examples=30, deadline=None, database=None, derandomize=True)
@given(data=st.data())
def test_values_in_range_are_accepted(verb, option, data):
    action = next(a for a in verb_parsers()[verb]._actions if option in a.option_strings)
    t: Number = action.type
    lo = t.min_value if math.isfinite(t.min_value) else -1e9
    hi = t.max_value if math.isfinite(t.max_value) else 1e9
    if t.integer:
        value = data.draw(st.integers(min_value=int(lo), max_value=int(hi)))
    else:
        value = data.draw(st.floats(min_value=lo, max_value=hi, exclude_min=not t.min_inclusive,
                                    exclude_max=not t.max_inclusive))
    assert t(repr(value)) == value
    assert (action.default is None or isinstance(action.default, str) or t.contains(action.default)), \
        f"{verb} {option}: default {action.default} outside {t.describe()}"


# ------------------------------------------------------------------------------- known failures


@pytest.fixture(scope="module")
def can_obj(tmp_path_factory) -> Path:
    from real2sim.geometry.objects import export_object

    return export_object("can", tmp_path_factory.mktemp("objects") / "can" / "model.obj")


@pytest.fixture(scope="module")
def huge_obj(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("objects") / "huge.obj"
    trimesh.creation.box(extents=(1000.0, 400.0, 300.0)).export(path)
    return path


@pytest.fixture
def work(tmp_path) -> Path:
    folder = tmp_path / "work"
    folder.mkdir()
    return folder


def _has_cuda() -> bool:
    import torch

    return torch.cuda.is_available()


ARGV_CASES = {
    # (argv after the verb, with MESH for the can, HUGE for a 1000 m box), text the one line must hold
    "asset --seed -1": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--seed", "-1"], "--seed"),
    "asset --seed 2**64": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--seed", str(2**64)], "--seed"),
    "capture --seed -1": (["capture", "MESH", "--out", "o", "--seed", "-1"], "--seed"),
    "capture --seed 2**32": (["capture", "MESH", "--out", "o", "--seed", str(2**32)], "--seed"),
    "refine-poses --seed 2**31": (["refine-poses", "ds", "--seed", str(2**31)], "--seed"),
    "asset --support-height-m nan": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--flat-bottom",
                                    "--support-height-m", "nan"], "--support-height-m"),
    "asset --support-height-m inf": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--flat-bottom",
                                    "--support-height-m=-inf"], "--support-height-m"),
    "asset --support-height-m above the mesh": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--flat-bottom",
                                               "--support-height-m", "0.5"], "leaves nothing of"),
    "asset --support-height-m below the mesh": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--flat-bottom",
                                               "--support-height-m", "-0.5"], "below"),
    "asset --device bogus": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--device", "bogus"], "--device"),
    "asset --device ''": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--device", ""], "--device"),
    "reconstruct --device bogus": (["reconstruct", "ds", "--out", "o", "--device", "bogus"], "--device"),
    "run --device ''": (["run", "ds", "--mass-kg", "0.3", "--out", "o", "--device="], "--device"),
    "mask --device cuda:x": (["mask", "ds", "--method", "maskrcnn", "--device", "cuda:x"], "--device"),
    "asset --vhacd-max-hulls 0": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--collision", "vhacd",
                                   "--vhacd-max-hulls", "0"], "--vhacd-max-hulls"),
    "asset --coacd-max-hulls 0": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--coacd-max-hulls", "0"],
                                  "--coacd-max-hulls"),
    "asset --mu-dynamic > --mu-static": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--mu-static", "0.3",
                                          "--mu-dynamic", "0.6"], "--mu-dynamic"),
    "asset --mass-kg 5000": (["asset", "MESH", "--mass-kg", "5000", "--out", "o"], "--mass-kg"),
    "asset 1000 m object": (["asset", "HUGE", "--mass-kg", "0.3", "--out", "o"], "1000 m across, over the largest object"),
    "asset object vs --resolution-hint-m": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--resolution-hint-m",
                                           "0.0001"], "--resolution-hint-m"),
    "asset --sdf-cache is a file": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--sdf-cache", "MESH"],
                                    "--sdf-cache"),
    "asset --sdf-cache under a file": (["asset", "MESH", "--mass-kg", "0.3", "--out", "o", "--sdf-cache", "MESH/c"],
                                       "--sdf-cache"),
    "mask --background-threshold 300": (["mask", "ds", "--method", "background", "--background-threshold", "300"], "--background-threshold"),
    "run --background-threshold 300": (["run", "ds", "--mass-kg", "0.3", "--out", "o", "--mask", "background",
                                  "--background-threshold", "300"], "--background-threshold"),
    "view --port 70000": (["view", "a", "--port", "70000"], "--port"),
    "view --port -1": (["view", "a", "--port", "-1"], "--port"),
    "view --host ''": (["view", "a", "--host", ""], "--host"),
    "demo --jobs 0": (["demo", "--jobs", "0"], "--jobs"),
    "run --jobs 0": (["run", "ds", "--mass-kg", "0.3", "--out", "o", "--jobs", "0"], "--jobs"),
    "refine-poses --max-features huge": (["refine-poses", "ds", "--max-features", str(10**9)], "--max-features"),
    "refine-poses --neighbors 0": (["refine-poses", "ds", "--neighbors", "0"], "--neighbors"),
    "capture --views 100000": (["capture", "MESH", "--out", "o", "--views", "100000"], "--views"),
    "capture --width-px 8": (["capture", "MESH", "--out", "o", "--width-px", "8"], "--width-px"),
    "capture --out under a file": (["capture", "MESH", "--out", "MESH/o", "--views", "2"], "file"),
    "reconstruct --voxels 100000": (["reconstruct", "ds", "--out", "o", "--voxels", "100000"], "--voxels"),
    "reconstruct --from-mesh missing": (["reconstruct", "ds", "--out", "o", "--from-mesh", "nope.ply",
                                         "--dataparser-transforms", "nope.json"], "--from-mesh"),
    "run --mask-weights missing": (["run", "ds", "--mass-kg", "0.3", "--out", "o", "--mask", "maskrcnn",
                                    "--mask-weights", "nope.pth"], "--mask-weights"),
}


@pytest.mark.parametrize("case", list(ARGV_CASES))
def test_known_failure_is_one_line_exit_2(case, work, can_obj, huge_obj):
    argv, expected = ARGV_CASES[case]
    argv = [a.replace("MESH", str(can_obj)).replace("HUGE", str(huge_obj)) for a in argv]
    before = sorted(os.listdir(can_obj.parent))
    code, err = run_in(work, argv)
    line = assert_one_line(code, err, expected)
    assert line.startswith(f"real2sim {argv[0]}: error:"), line
    assert os.listdir(work) == [] and sorted(os.listdir(can_obj.parent)) == before, "nothing may be written"


def test_cuda_without_a_gpu_is_refused_while_parsing(work):
    if _has_cuda():
        pytest.skip("this machine has CUDA")
    for argv in (["asset", "m.obj", "--mass-kg", "1", "--out", "o", "--device", "cuda"],
                 ["reconstruct", "ds", "--out", "o", "--device", "cuda:0"],
                 ["mask", "ds", "--method", "maskrcnn", "--device", "cuda"]):
        code, err = run_in(work, argv)
        assert "no CUDA" in assert_one_line(code, err, "--device")
    assert os.listdir(work) == []


def test_sdf_cache_accepts_auto_and_a_new_folder(work):
    from real2sim.cli.options import cache_dir

    assert cache_dir("auto") == "auto"
    assert cache_dir(str(work / "new" / "cache")) == str(work / "new" / "cache")
    assert not (work / "new").exists(), "checking a cache folder makes nothing"


# ------------------------------------------------------------------------------- datasets


def _damaged_dataset(root: Path, case: str) -> Path:
    _make_dataset(root, n=4, w=32, h=24)
    if case == "corrupt image":
        (root / "images/im1.png").write_bytes((root / "images/im1.png").read_bytes()[:50])
    elif case == "empty image":
        (root / "images/im1.png").write_bytes(b"")
    elif case == "image of another size":
        Image.new("RGB", (40, 30)).save(root / "images/im1.png")
    elif case == "mask of another size":
        Image.new("L", (16, 12)).save(root / "masks/im2.png")
    elif case in ("path outside the folder", "absolute path outside the folder"):
        Image.new("RGB", (32, 24)).save(root.parent / "outside.png")
        data = json.loads((root / "transforms.json").read_text())
        data["frames"][1]["file_path"] = ("../outside.png" if case == "path outside the folder"
                                          else str(root.parent / "outside.png"))
        (root / "transforms.json").write_text(json.dumps(data))
    return root


DATASET_CASES = {
    "corrupt image": "images/im1.png is not a readable image",
    "empty image": "images/im1.png is empty",
    "image of another size": "images/im1.png is 40x30 px, but the dataset's camera is 32x24",
    "mask of another size": "masks/im2.png is 16x12 px",
    "path outside the folder": "points outside the dataset folder",
    "absolute path outside the folder": "points outside the dataset folder",
}


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("verb", ["refine-poses", "mask", "reconstruct", "run"])
@pytest.mark.parametrize("case", list(DATASET_CASES))
def test_bad_dataset_is_refused_up_front(verb, case, tmp_path):
    ds = _damaged_dataset(tmp_path / "ds", case)
    before = _snapshot(tmp_path)
    argv = {"refine-poses": ["refine-poses", ds], "mask": ["mask", ds, "--method", "provided"],
            "reconstruct": ["reconstruct", ds, "--out", tmp_path / "mesh", "--backend", "hull"],
            "run": ["run", ds, "--mass-kg", "0.3", "--out", tmp_path / "asset", "--backend", "hull"]}[verb]
    code, err = run_in(tmp_path, argv)
    assert_one_line(code, err, DATASET_CASES[case])
    assert _snapshot(tmp_path) == before, "nothing may be written"


def test_dataset_outputs_that_cannot_be_written_are_refused(tmp_path):
    ds = tmp_path / "ds"
    _make_dataset(ds, n=4, w=32, h=24)
    (ds / "refine_report.json").mkdir()
    (ds / "masks_background").write_text("a file where the masks' folder goes")
    before = _snapshot(tmp_path)
    code, err = run_in(tmp_path, ["refine-poses", ds])
    assert_one_line(code, err, "refine_report.json is a folder")
    code, err = run_in(tmp_path, ["mask", ds, "--method", "background"])
    assert_one_line(code, err, "masks_background is a file")
    assert _snapshot(tmp_path) == before
