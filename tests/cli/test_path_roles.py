"""Every path a verb takes is declared as read, written, edited in place or a cache, and no output
may be, contain or lie inside anything read (issue: `--overwrite` deleted a user's input in six
cases). The cases are enumerated from the parser itself, so a new path option cannot escape."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from real2sim.cli import build_parser, options
from real2sim.plumbing.inputs import check_outputs_spare_inputs, companion_files
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import MARKER_NAME
from tests.cli_helpers import run_cli

PATH_TYPES = (options.path, options.existing_file, options.existing_dir, options.cache_dir, Path)
PATH_WORDS = ("FILE", "DIR", "MESH", "PDF", "PNG", "CSV", "URDF", "LOG", "PATH", "JSON", "DATASET", "RESULTS",
              "CATALOGUE", "OBJECT", "VIDEO", ".json", ".obj")
#: Options that look like paths but are not paths a verb opens as given, with the reason.
NOT_PATHS = {
    ("batch", "mass_from"): "a file name looked up inside each DATASET, which is declared",
}
#: Folders (the rest of the read paths are files) for the enumerated cases below.
FOLDER_INPUTS = {"dataset", "datasets", "log", "shape", "assets", "asset", "results"}
#: The other arguments each verb that writes needs to get past argparse.
REQUIRED = {
    "capture": {"mesh": None},
    "reconstruct": {"dataset": None},
    "asset": {"mesh": None, "--mass-kg": "0.4"},
    "run": {"dataset": None, "--mass-kg": "0.4"},
    "batch": {"datasets": None, "--mass-kg": "0.4"},
    "excite": {"object": None, "--mass-kg": "0.4"},
    "identify": {"log": None},
    "evaluate": {"assets": None},
}


def verb_parsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def roles_of(parser: argparse.ArgumentParser) -> dict[str, tuple[str, str]]:
    return parser.get_default("path_roles") or {}


def looks_like_path(action: argparse.Action) -> bool:
    if action.nargs == 0 or action.dest == "help":
        return False
    return action.type in PATH_TYPES or any(w in str(action.metavar or "") for w in PATH_WORDS)


@pytest.mark.parametrize("verb", sorted(verb_parsers()))
def test_every_path_option_is_declared(verb):
    parser = verb_parsers()[verb]
    roles = roles_of(parser)
    undeclared = [a.dest for a in parser._actions
                  if looks_like_path(a) and a.dest not in roles and (verb, a.dest) not in NOT_PATHS]
    assert not undeclared, f"{verb}: path options with no role in options.declare_paths: {undeclared}"
    assert all(role in options.PATH_ROLES for role, _ in roles.values())


def writes_and_reads() -> list[tuple[str, str]]:
    cases = []
    for verb, parser in verb_parsers().items():
        roles = roles_of(parser)
        if any(role == "writes" for role, _ in roles.values()):
            cases += [(verb, dest) for dest, (role, _) in roles.items() if role == "reads"]
    return sorted(cases)


def test_every_verb_that_writes_and_reads_has_a_case():
    verbs = {verb for verb, _ in writes_and_reads()}
    assert verbs == set(REQUIRED), "add the new verb's required arguments to REQUIRED"


def argv_for(verb: str, dest: str, value: Path, out: Path) -> list[str]:
    parser = verb_parsers()[verb]
    actions = {a.dest: a for a in parser._actions}
    given = dict(REQUIRED[verb])
    if dest == "masses":  # one of --mass-kg, --masses, --mass-from
        given.pop("--mass-kg")
    argv = [verb]
    for key, text in given.items():
        if key.startswith("--"):
            argv += [key, text]
        else:
            argv.append(str(value) if key == dest else str(out.parent / "elsewhere" / key))
    if dest not in given:
        argv += [actions[dest].option_strings[-1], str(value)]
    argv += ["--out", str(out)]
    if "overwrite" in actions:
        argv.append("--overwrite")
    return argv


def make_input(path: Path, dest: str) -> bytes:
    if dest in FOLDER_INPUTS:
        path.mkdir(parents=True)
        (path / "data.txt").write_text("mine")
        return (path / "data.txt").read_bytes()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("mine")
    return path.read_bytes()


@pytest.mark.parametrize("relation", ["contains", "is"])
@pytest.mark.parametrize("verb,dest", writes_and_reads())
def test_overwrite_never_removes_what_a_verb_reads(tmp_path, monkeypatch, capsys, verb, dest, relation):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "elsewhere").mkdir()
    out = tmp_path / "out"
    out.mkdir()
    (out / MARKER_NAME).write_text("{}")  # an earlier real2sim output: --overwrite may replace it
    source = out / f"my_{dest}" if relation == "contains" else out
    if relation == "is":
        (out / MARKER_NAME).unlink()
        out.rmdir()
    before = make_input(source, dest)
    code, _, err = run_cli(capsys, *argv_for(verb, dest, source, out))
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert "input" in err and relation in err, err
    kept = source / "data.txt" if dest in FOLDER_INPUTS else source
    assert kept.read_bytes() == before


def test_a_folder_inside_an_input_folder_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    log = tmp_path / "log"
    log.mkdir()
    (log / "joints.csv").write_text("t,q\n")
    code, _, err = run_cli(capsys, "identify", log, "--out", log / "joints.csv", "--overwrite")
    assert code == 2 and "lies inside the input" in err and "LOG" in err
    assert (log / "joints.csv").read_text() == "t,q\n"


def test_files_an_obj_reads_are_inputs_too(tmp_path, monkeypatch, capsys):
    """A mesh whose material and texture live in another folder: that folder is an input as well."""
    monkeypatch.chdir(tmp_path)
    assert run_cli(capsys, "objects", "export", "can", tmp_path / "can.obj")[0] == 0
    materials = tmp_path / "materials"
    materials.mkdir()
    for item in tmp_path.glob("can*"):
        if item.suffix != ".obj":
            item.rename(materials / item.name)
    obj = tmp_path / "can.obj"
    obj.write_text(obj.read_text().replace("mtllib ", "mtllib materials/"))
    mtl = next(materials.glob("*.mtl"))
    texture = next(materials.glob("*.png"))
    assert set(companion_files(obj)) >= {mtl, materials / mtl.read_text().split("map_Kd")[1].split()[0]}
    (materials / MARKER_NAME).write_text("{}")
    before = texture.read_bytes()
    code, _, err = run_cli(capsys, "asset", obj, "--mass-kg", "0.4", "--out", materials, "--overwrite")
    assert code == 2 and "a file that MESH reads" in err, err
    assert texture.read_bytes() == before


def test_a_urdf_brings_its_meshes(tmp_path):
    robot = tmp_path / "robot" / "arm.urdf"
    robot.parent.mkdir()
    robot.write_text('<robot name="a"><link name="l"><visual><geometry><mesh filename="../meshes/l.obj"/>'
                     '</geometry></visual></link><link name="m"><visual><geometry>'
                     '<mesh filename="package://x/y.obj"/></geometry></visual></link></robot>')
    assert companion_files(robot) == [tmp_path / "meshes" / "l.obj"]
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "l.obj").write_text("v 0 0 0\n")
    with pytest.raises(UserInputError, match="contains the input"):
        check_outputs_spare_inputs([("--out", tmp_path / "meshes")], [("--robot", robot)])
    check_outputs_spare_inputs([("--out", tmp_path / "log")], [("--robot", robot)])  # apart: fine


def test_a_bundled_name_is_no_path(tmp_path, monkeypatch):
    """`excite can --out can`: the object is the bundled can, not a folder named can."""
    monkeypatch.chdir(tmp_path)
    check_outputs_spare_inputs([("--out", Path("can"))], [("OBJECT|MESH", Path("can"))])


def roles_table() -> list[str]:
    """The rows of docs/reliability.md's path-role table, as the parser declares them."""
    rows = []
    for verb, parser in verb_parsers().items():
        roles = roles_of(parser)
        cells = [", ".join(f"`{label}`".replace("|", "\\|") for _, (r, label) in roles.items() if r == role)
                 for role in options.PATH_ROLES]
        rows.append(f"| `{verb}` | " + " | ".join(cells) + " |")
    return rows


def test_the_reliability_page_lists_every_verbs_paths():
    text = (Path(__file__).parents[2] / "docs" / "reliability.md").read_text()
    start = text.index("<!-- path roles")
    end = text.index("<!-- end of path roles -->")
    documented = [line for line in text[start:end].splitlines() if line.startswith("| `")]
    assert documented == roles_table(), "regenerate the table: " + "\n".join(roles_table())


def test_the_library_refuses_too(tmp_path, monkeypatch, capsys):
    """build_asset, called from Python, keeps the same rule for the properties file it reads."""
    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.formats.physical import read_given_properties
    from real2sim.formats.spec import parse_spec

    monkeypatch.chdir(tmp_path)
    assert run_cli(capsys, "objects", "export", "can", tmp_path / "can.obj")[0] == 0
    out = tmp_path / "asset"
    out.mkdir()
    (out / MARKER_NAME).write_text("{}")
    props = out / "props.json"
    props.write_text('{"mass_kg": 0.4, "com_m": [0, 0, 0.05], "inertia_kg_m2": [[1e-3, 0, 0], [0, 1e-3, 0], '
                     '[0, 0, 1e-3]]}')
    given, frame = read_given_properties(props)
    config = AssetConfig(mass_kg=0.4, specs=(parse_spec("spheres:4"),), given_properties=given,
                         given_properties_frame=frame,
                         given_properties_source=str(props))
    with pytest.raises(UserInputError, match="contains the input"):
        build_asset(tmp_path / "can.obj", out, config, overwrite=True)
    assert props.exists()
