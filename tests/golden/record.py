"""Golden outputs of three fixed small pipelines, recorded before the source tree is regrouped, so that
tests/test_behaviour_unchanged.py can show afterwards that the same files come out with the same numbers.

Everything goes through the command line (the `real2sim` console script in a subprocess, never an
internal module), so moving modules cannot break the recorder or the test themselves.

    .venv/bin/python -m tests.golden.record                  # (re)write tests/golden/<pipeline>.json
    .venv/bin/python -m tests.golden.record --only asset --runs 3

Each pipeline runs --runs times (default 2; 3 for a pipeline marked nondeterministic), each time in another
temporary folder, so an absolute path written into a file shows up as a difference. Every file under the
pipeline's folder afterwards is recorded:

  * a file whose bytes are the same in every run: its SHA-256, and its numbers too (below), and for a text
    file the SHA-256 of its layout (the text with every number masked). Bytes that change later pass when
    the layout is the recorded one and the numbers agree within the tolerance: the last digits of a float
    follow the machine's and the libraries' rounding (a numpy or BLAS update reorders a sum), and the
    comparison must not fail a clean install for that; a changed word, key or format still fails;
  * a file whose bytes vary: its numbers, under these rules --
      - JSON: every numeric leaf (int, float, bool, null) by its key path, except fields named like a
        timing, date, path, host, version, memory or hash (IGNORED_KEY, IGNORED_FIELDS);
      - meshes (.obj .stl .ply): vertex and face counts, bounds and volume (trimesh);
      - images (.png .jpg): their size in pixels only;
      - URDF / SDF / XML / USDA / MTL / TXT / CSV text: every number in the text, in order;
      - anything else: only that it exists.
    Integers compare exactly, other numbers with a relative tolerance of 1e-6 (absolute 1e-12, and 1e-9 m
    for mesh bounds and volume, for values near zero).

For a deterministic pipeline the recorder refuses to write while a number left after these rules still
differs between its runs, so the rules cannot hide a result that varies unnoticed. In a pipeline marked
nondeterministic (NONDETERMINISTIC says why) a file whose bytes vary keeps only that it exists and its settings
(SETTINGS_FIELDS: numbers that are the command's and the program's choices, not results); the byte-stable
files keep their hashes. Its results vary by more than any tolerance that would still mean something (the
hull's face count), and even which fields a JSON file has depends on them (sfm.json's change_pct is there
only when the board's focal length was used, which two halves of the board views agreeing within 0.5 %
decides: 0.53 % in one run), so no key structure is compared there either.
"""

from __future__ import annotations

import argparse
import fnmatch
import hashlib
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

GOLDEN = Path(__file__).resolve().parent

# --------------------------------------------------------------------------------------------- pipelines
# Paths in the commands are {root}/...: the pipeline's own folder, all of whose files are its outputs.
# No --threads: the outputs were measured the same with torch on 1 and on 2 threads (robot_capture and
# asset byte for byte, apart from their timings).

# The smallest visual-hull settings the project's own tests use (tests/pipeline/test_phone_reliability.py).
SMALL_HULL = ["--backend", "hull", "--voxels", "48", "--max-faces", "2000", "--texture-px", "64"]

PIPELINES: dict[str, list[list[str]]] = {
    # a. a seeded simulated robot capture of the bundled can -> run: visual hull, no pose refinement
    "robot_capture": [
        ["capture", "can", "--views", "24", "--width-px", "96", "--height-px", "72", "--seed", "0",
         "--out", "{root}/DS"],
        ["run", "{root}/DS", "--mass-kg", "0.35", "--out", "{root}/A", *SMALL_HULL,
         "--collision", "cylinders:4", "--collision", "spheres:8", "--iterations", "50", "--no-refine-poses"],
    ],
    # b. a seeded phone capture on the printed board -> run: SfM, board frame, parallax masks, hull, asset.
    #    60 photos at 160x120, where the parallax masks say they work: with 24 photos (320x240, as
    #    tests/pipeline/test_phone.py, or 192x144) they warn that they cannot be trusted, and the reconstruct
    #    stage refused about one run in eight (a hull three times the can's size); 60 at 160x120: 5 of 5 ran.
    "phone_capture": [
        ["capture", "can", "--handheld", "--with-board", "--views", "60", "--width-px", "160", "--height-px", "120",
         "--seed", "0", "--out", "{root}/PHOTOS"],
        ["run", "{root}/PHOTOS", "--mass-kg", "0.35", "--out", "{root}/B", *SMALL_HULL,
         "--collision", "spheres:4", "--iterations", "30"],
    ],
    # c. asset of a bundled mesh with every collision family once, small counts, every model format
    "asset": [
        ["objects", "export", "bottle", "{root}/bottle.obj"],
        ["asset", "{root}/bottle.obj", "--mass-kg", "0.6", "--out", "{root}/C",
         "--collision", "spheres:4", "--collision", "boxes:2", "--collision", "rotated_boxes:2",
         "--collision", "cylinders:2", "--collision", "ellipsoids:2", "--collision", "capsules:2",
         "--collision", "superquadrics:1", "--collision", "coacd", "--collision", "vhacd",
         "--vhacd-max-hulls", "4", "--collision", "mesh", "--iterations", "30",
         "--format", "sdf", "--format", "mjcf", "--format", "usd"],
    ],
}

#: Pipelines whose outputs differ run to run for a reason no command-line option removes.
NONDETERMINISTIC: dict[str, str] = {
    "phone_capture": (
        "structure from motion (COLMAP through pycolmap) runs on every core: the sfm stage's num_threads is -1 "
        "and no option of `run` sets it (--threads is torch's), and COLMAP counts the machine's cores, not "
        "the process's CPU affinity. Its threads' order changes the focal length (125.54 / 125.64 / 125.75 px "
        "in the three recorded runs), the poses, and so every result downstream of the sfm stage (the hull "
        "mesh's vertices: 2129 / 1937 / 2095; with 24 photos its faces were 2000 three times, 580 once); the "
        "photos and the copies of their ground truth are byte-stable"),
}


#: In a nondeterministic pipeline, the numbers of a varying file that are still compared: "FILE::FIELD"
#: (fnmatch on the file's relative path and the field's key path).
SETTINGS_FIELDS = [
    "*/run.json::stages.*.settings.*",
    "*/run.json::stages.sfm.inputs.*",  # the photos: upstream of structure from motion
    "*/report.json::config.*",
    "*/board_frame.json::board.*",
    "*/asset_config.json::*",
    "*/physical_properties.json::mass_kg",
    "*/truth.json::physical_properties.mass_kg",
    "*/fit_report.json::requested_count",
    "*/fit_report.json::iterations",
]


def golden_path(name: str) -> Path:
    return GOLDEN / f"{name}.json"


def real2sim_command() -> list[str]:
    """The installed console script next to this interpreter, else ``python -m real2sim``."""
    script = Path(sys.executable).with_name("real2sim")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "real2sim"]


def pipeline_env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("REAL2SIM_")}  # no cache, no thread default
    env.update(OMP_WAIT_POLICY="PASSIVE", PYTHONHASHSEED="0", TZ="UTC")
    return env


def run_pipeline(name: str, root: Path) -> float:
    """Run pipeline NAME's commands, everything written under ROOT (must not exist); its wall seconds."""
    root.mkdir(parents=True)
    start = time.perf_counter()
    for argv in PIPELINES[name]:
        argv = [a.replace("{root}", str(root)) for a in argv]
        proc = subprocess.run([*real2sim_command(), *argv], env=pipeline_env(), cwd=root,
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"pipeline {name}: `real2sim {' '.join(argv)}` exited {proc.returncode}:\n"
                               f"{proc.stderr[-4000:]}")
    return time.perf_counter() - start


# ------------------------------------------------------------------------------------------------ rules

REL_TOL = 1e-6
ABS_TOL = 1e-12
MESH_ABS_TOL = 1e-9  # metres
MAX_TEXT_NUMBERS = 5000  # a byte-stable text keeps its numbers only when it has at most this many, else a sample
TEXT_SAMPLE = 200  # numbers of such a sample, evenly spaced by position

SUFFIX_KINDS = {".json": "json", ".obj": "mesh", ".stl": "mesh", ".ply": "mesh", ".png": "image",
                ".jpg": "image", ".jpeg": "image", ".urdf": "text", ".sdf": "text", ".xml": "text",
                ".usda": "text", ".mtl": "text", ".txt": "text", ".csv": "text"}

#: JSON keys whose numbers are timings, dates, paths, hosts, versions, memory or hashes of inputs that hold
#: those: they change run to run (or machine to machine) without the behaviour changing. A key path is
#: left out when any key on it matches.
IGNORED_KEY = re.compile(r"second|time|date|peak|memory|path|host|version|software|sha256|_at$|_s$|_ms$")
#: Whole fields, by key path (fnmatch), that vary for a reason their names do not say: the byte size of a
#: stage's input files (run.json), which changes when a timing in them gains a digit or a float's last digit
#: rounds otherwise; those files are compared themselves, number by number.
IGNORED_FIELDS = ["stages.*.inputs.*.bytes"]


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def kind_of(path: Path) -> str:
    return SUFFIX_KINDS.get(path.suffix.lower(), "other")


def _is_ignored(keys: tuple[str, ...], dotted: str) -> bool:
    """Whether the JSON field at key path ``dotted`` (its keys ``keys``, the field's own last) is left out."""
    return (any(IGNORED_KEY.search(x.lower()) for x in keys)
            or any(fnmatch.fnmatchcase(dotted, p) for p in IGNORED_FIELDS))


def _json_leaves(value, keys: tuple[str, ...], dotted: str, out: dict, ignored: list) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            child = f"{dotted}.{k}" if dotted else str(k)
            if _is_ignored((*keys, str(k)), child):
                ignored.append(child)
                continue
            _json_leaves(v, (*keys, str(k)), child, out, ignored)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _json_leaves(v, keys, f"{dotted}[{i}]", out, ignored)
    elif isinstance(value, (bool, int, float)) or value is None:
        if dotted in out:
            raise ValueError(f"two JSON fields read as {dotted!r}")
        out[dotted] = value


def json_numbers(value) -> tuple[dict, list[str]]:
    """({key path: number} of VALUE's numeric leaves outside the ignored fields, [ignored key paths])."""
    out, ignored = {}, []
    _json_leaves(value, (), "", out, ignored)
    return out, ignored


NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def text_numbers(path: Path) -> list[float]:
    return [float(m) for m in NUMBER.findall(path.read_text(errors="replace"))]


def _without_ignored(value, keys: tuple[str, ...] = (), dotted: str = ""):
    """VALUE with every field that :data:`IGNORED_KEY` or :data:`IGNORED_FIELDS` names replaced by a mark."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            child = f"{dotted}.{k}" if dotted else str(k)
            out[k] = "(ignored)" if _is_ignored((*keys, str(k)), child) else _without_ignored(v, (*keys, str(k)), child)
        return out
    if isinstance(value, list):
        return [_without_ignored(v, keys, f"{dotted}[{i}]") for i, v in enumerate(value)]
    return value


def layout_sha256(path: Path) -> str | None:
    """SHA-256 of the file's text with every number masked; None for a file that is not UTF-8 text. A JSON
    file's layout leaves out its ignored fields too: an input's hash is hex text whose digits fall where they
    may, a version string may gain a part, and neither is behaviour."""
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        return None
    if kind_of(path) == "json":
        try:
            text = json.dumps(_without_ignored(json.loads(text)), indent=1, sort_keys=True)
        except ValueError:
            pass  # not JSON after all: its text as it is
    return hashlib.sha256(NUMBER.sub("#", text).encode()).hexdigest()


def number_sample(numbers: list[float]) -> dict:
    """What stands for a text's numbers where there are too many to keep one by one: every k-th number
    (at most TEXT_SAMPLE of them, by position) and sums over all of them. A change that moves many
    numbers shows; one number between the kept ones can move unseen while the layout hash holds."""
    step = -(-len(numbers) // TEXT_SAMPLE)
    return {**{f"#{i}": numbers[i] for i in range(0, len(numbers), step)},
            "sum_abs": math.fsum(abs(x) for x in numbers), "sum_sq": math.fsum(x * x for x in numbers)}


def mesh_numbers(path: Path) -> dict:
    import trimesh

    mesh = trimesh.load(path, force="mesh", process=False)
    values = {"vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces))}
    for row, end in zip(mesh.bounds, ("min", "max")):
        values.update({f"bounds.{end}.{axis}": float(x) for axis, x in zip("xyz", row)})
    values["volume"] = float(mesh.volume)
    return values


def image_size(path: Path) -> dict:
    from PIL import Image

    with Image.open(path) as image:
        return {"width": int(image.width), "height": int(image.height)}


def numbers_of(path: Path, kind: str, byte_stable: bool = False) -> dict:
    """The numbers of one file under its kind's rule: {"values": {name: number}, ["ignored": [...]]}."""
    if kind == "json":
        values, ignored = json_numbers(json.loads(path.read_text()))
        return {"values": values, "ignored": sorted(ignored)}
    if kind == "mesh":
        return {"values": mesh_numbers(path)}
    if kind == "image":
        return {"values": image_size(path)}
    if kind == "text":
        numbers = text_numbers(path)
        values = {"count": len(numbers)}
        if not byte_stable or len(numbers) <= MAX_TEXT_NUMBERS:
            values.update({f"#{i}": x for i, x in enumerate(numbers)})
        else:
            values.update(number_sample(numbers))
        return {"values": values}
    return {"values": {}}


def settings_only(rel: str, values: dict) -> dict:
    """The VALUES of file REL that SETTINGS_FIELDS names."""
    patterns = [p.split("::", 1) for p in SETTINGS_FIELDS]
    return {n: v for n, v in values.items()
            if any(fnmatch.fnmatchcase(rel, f) and fnmatch.fnmatchcase(n, k) for f, k in patterns)}


def loose_summary(rel: str, path: Path) -> dict:
    """A varying file of a nondeterministic pipeline: only its settings."""
    kind = kind_of(path)
    return {"kind": kind, "compared": "that it exists, and its settings (nondeterministic pipeline)",
            "values": settings_only(rel, numbers_of(path, kind)["values"])}


def summarise(path: Path, byte_stable: bool) -> dict:
    kind = kind_of(path)
    entry = {"kind": kind}
    if byte_stable:
        entry["sha256"] = sha256(path)
        layout = layout_sha256(path) if kind in ("json", "text", "mesh") else None
        if layout is not None:
            entry["layout_sha256"] = layout
    entry.update(numbers_of(path, kind, byte_stable))
    return entry


def output_files(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())


# ------------------------------------------------------------------------------------------- comparison


def close(a, b, abs_tol: float = ABS_TOL) -> bool:
    if isinstance(a, bool) or isinstance(b, bool) or a is None or b is None:
        return a is b or (a == b and type(a) is type(b))
    if isinstance(a, int) and isinstance(b, int):
        return a == b
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return math.isclose(a, b, rel_tol=REL_TOL, abs_tol=abs_tol)


def compare_values(kind: str, expected: dict, actual: dict) -> list[str]:
    """Differences between two numbers_of() values of one file, one line each (empty: the same)."""
    what = {"json": "field", "text": "number", "mesh": "mesh", "image": "image"}.get(kind, "value")
    problems = []
    for name in sorted(set(expected) | set(actual), key=_natural):
        if name not in actual:
            problems.append(f"{what} {name}: missing (was {expected[name]!r})")
        elif name not in expected:
            problems.append(f"{what} {name}: new (now {actual[name]!r})")
        elif not close(expected[name], actual[name],
                       MESH_ABS_TOL if kind == "mesh" else ABS_TOL):
            problems.append(f"{what} {name}: {expected[name]!r} -> {actual[name]!r}")
    return problems


def _natural(name: str):
    return (0, int(name[1:]), "") if name.startswith("#") and name[1:].isdigit() else (1, 0, name)


def compare_outputs(golden: dict, root: Path, limit: int = 20) -> list[str]:
    """Every difference between the recorded GOLDEN and the files now under ROOT, as 'FILE: what' lines
    (at most LIMIT lines for one file, then how many more)."""
    problems = []
    expected_files = golden["files"]
    actual_files = set(output_files(root))
    for rel in sorted(set(expected_files) - actual_files):
        problems.append(f"{rel}: missing (it was written when recorded)")
    for rel in sorted(actual_files - set(expected_files)):
        problems.append(f"{rel}: new file (not written when recorded)")
    for rel in sorted(set(expected_files) & actual_files):
        exp, path = expected_files[rel], root / rel
        try:
            act = loose_summary(rel, path) if "compared" in exp else numbers_of(path, exp["kind"], "sha256" in exp)
        except Exception as exc:  # an output that no longer reads as its kind is a difference too
            problems.append(f"{rel}: cannot be read as {exp['kind']}: {exc}")
            continue
        found = compare_values(exp["kind"], exp["values"], act["values"])
        if "sha256" in exp:
            digest = sha256(path)
            if digest != exp["sha256"]:
                if not found and layout_sha256(path) == exp.get("layout_sha256", ""):
                    continue  # the same text and the same numbers to the tolerance: only float rounding moved
                why = ("" if found else ": the numbers agree within the tolerance, but the text around them changed"
                       if "layout_sha256" in exp else ": the numbers agree within the tolerance")
                found.insert(0, f"bytes changed (byte-stable when recorded; sha256 {exp['sha256'][:12]}... -> "
                                f"{digest[:12]}...){why}")
        if len(found) > limit:
            found = [*found[:limit], f"... and {len(found) - limit} more differences"]
        problems.extend(f"{rel}: {p}" for p in found)
    return problems


# -------------------------------------------------------------------------------------------- recording


def record(name: str, runs: int, keep: Path | None = None) -> dict:
    with tempfile.TemporaryDirectory(prefix=f"golden-{name}-") as tmp:
        base = keep if keep is not None else Path(tmp)
        roots, seconds = [], []
        for i in range(runs):
            root = base / f"run{i}" / name  # another absolute path each time
            if root.exists():
                shutil.rmtree(root)
            seconds.append(run_pipeline(name, root))
            roots.append(root)
            print(f"{name}: run {i + 1}/{runs}: {seconds[-1]:.1f} s", file=sys.stderr)
        listings = [output_files(r) for r in roots]
        for i, listing in enumerate(listings[1:], 2):
            if listing != listings[0]:
                raise RuntimeError(f"{name}: run {i} wrote other files than run 1: "
                                   f"{sorted(set(listing) ^ set(listings[0]))[:20]}")
        files, varying = {}, []
        for rel in listings[0]:
            stable = len({sha256(r / rel) for r in roots}) == 1
            if stable:
                files[rel] = summarise(roots[0] / rel, True)
                continue
            varying.append(rel)
            if name in NONDETERMINISTIC:
                files[rel] = loose_summary(rel, roots[0] / rel)
                for r in roots[1:]:
                    other = loose_summary(rel, r / rel)
                    if other != files[rel]:
                        raise RuntimeError(f"{name}: {rel}: its settings differ between runs: "
                                           f"{compare_values(other['kind'], files[rel]['values'], other['values'])}"
                                           " (SETTINGS_FIELDS names a result?)")
                continue
            files[rel] = summarise(roots[0] / rel, False)
            for r in roots[1:]:
                other = numbers_of(r / rel, files[rel]["kind"])["values"]
                diff = compare_values(files[rel]["kind"], files[rel]["values"], other)
                if diff:
                    raise RuntimeError(f"{name}: {rel} differs between runs beyond the rules: {diff[:20]}")
    golden = {
        "pipeline": name,
        "commands": PIPELINES[name],
        "nondeterministic": NONDETERMINISTIC.get(name),
        "recorded_runs": runs,
        "recorded_seconds": [round(s, 1) for s in seconds],
        "rules": {"rel_tol": REL_TOL, "abs_tol": ABS_TOL, "mesh_abs_tol_m": MESH_ABS_TOL,
                  "ignored_key": IGNORED_KEY.pattern, "ignored_fields": IGNORED_FIELDS},
        "byte_stable_files": len(files) - len(varying),
        "compared_by_numbers": varying,
        "files": files,
    }
    golden_path(name).write_text(json.dumps(golden, indent=1) + "\n")
    print(f"{name}: {len(files)} files, {len(files) - len(varying)} byte-stable, {len(varying)} by numbers"
          + (" (existence and settings only: nondeterministic)" if name in NONDETERMINISTIC else ""),
          file=sys.stderr)
    return golden


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.golden.record",
                                     description="(re)write tests/golden/<pipeline>.json")
    parser.add_argument("--only", action="append", choices=sorted(PIPELINES), help="record just these")
    parser.add_argument("--runs", type=int, help="runs per pipeline that find its byte-stable files "
                                                 "(default 2, 3 for a nondeterministic pipeline)")
    parser.add_argument("--keep", type=Path, help="run in this folder and keep the outputs")
    args = parser.parse_args(argv)
    for name in args.only or list(PIPELINES):
        runs = args.runs or (3 if name in NONDETERMINISTIC else 2)
        record(name, max(1, runs), args.keep)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
