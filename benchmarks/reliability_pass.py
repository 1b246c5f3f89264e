"""A pass of bad inputs over every verb and option, enumerated from the parser (docs/reliability.md).

For each option of each verb, values of the classes that broke the contract before: numbers out of
range or not finite, unknown choices, and, for paths, what a user's file system holds in place of
the right file (nothing, a folder for a file, a file for a folder, an empty or garbage file, a link
to nothing, a link loop, a path under a file; for outputs also a folder real2sim did not make, an
overlong name; an output over an input is tests/cli/test_path_roles.py's, for every pair). Every other
argument is a valid small input made first. Each case runs as its own `real2sim` process with a time
limit and is judged by the contract: exit 2 with exactly one line and no traceback ("refused"),
otherwise "internal error" (exit 1 or a traceback), "several lines", "accepted" (exit 0: to be read
by a person, some values are legitimately accepted) or "still running" at the limit.

    python benchmarks/reliability_pass.py [--jobs 2] [--limit-s 60]

Writes benchmarks/results/reliability_pass.md and .json (machine, date, command) via benchmarks/common.py.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import markdown_table, write_result  # noqa: E402

from real2sim.cli import build_parser, options  # noqa: E402

REAL2SIM = [sys.executable, "-m", "real2sim"]
#: Small valid inputs, made once: name -> argv (OUT is replaced by the path).
SETUP = {
    "mesh": ["objects", "export", "can", "OUT/can.obj"],
    "dataset": ["capture", "can", "--views", "12", "--width-px", "96", "--height-px", "72", "--out", "OUT"],
    "log": ["excite", "can", "--mass-kg", "0.4", "--duration-s", "8", "--out", "OUT"],
    "asset": ["asset", "WORK/mesh/can.obj", "--mass-kg", "0.4", "--collision", "spheres:4", "--iterations", "10",
              "--out", "OUT"],
    "board": ["board", "--out", "OUT/board.pdf"],
}
#: A valid command of each verb, as (positionals, options); {name} is a SETUP input, {new} a fresh output path.
VALID = {
    "demo": ([], ["--quick", "--out", "{new}"]),
    "objects": (["export", "can", "{new}.obj"], []),
    "capture": (["can"], ["--views", "12", "--width-px", "96", "--height-px", "72", "--out", "{new}"]),
    "refine-poses": (["{dataset}"], []),
    "mask": (["{dataset}"], ["--method", "provided"]),
    "board": ([], ["--out", "{new}.pdf"]),
    "reconstruct": (["{dataset}"], ["--backend", "hull", "--out", "{new}"]),
    "asset": (["{mesh}/can.obj"], ["--mass-kg", "0.4", "--collision", "spheres:4", "--iterations", "10", "--out", "{new}"]),
    "run": (["{dataset}"], ["--mass-kg", "0.4", "--backend", "hull", "--collision", "spheres:4", "--iterations", "10",
                            "--no-refine-poses", "--out", "{new}"]),
    "batch": (["{dataset}"], ["--mass-kg", "0.4", "--backend", "hull", "--collision", "spheres:4", "--iterations", "10",
                              "--no-refine-poses", "--out", "{new}"]),
    "excite": (["can"], ["--mass-kg", "0.4", "--duration-s", "8", "--out", "{new}"]),
    "identify": (["{log}"], ["--out", "{new}.json"]),
    "evaluate": (["{asset}"], ["--runs", "1", "--tasks", "push", "--contact", "point", "--out", "{new}"]),
    "report": (["{new}"], []),
}
#: Verbs whose valid command cannot run here without a person or a browser: path classes only
#: where the value is checked before anything starts.
SKIP_VERBS = {"view", "demo"}


def verb_parsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def number_values(kind: options.Number) -> list[str]:
    values = ["nan", "inf", "-inf", "1e999", "abc", ""]
    if math.isfinite(kind.min_value):
        values.append(str(int(kind.min_value) - 1 if kind.integer else kind.min_value - abs(kind.min_value) - 1))
    if math.isfinite(kind.max_value):
        values.append(str(int(kind.max_value) * 10 + 1 if kind.integer else kind.max_value * 10 + 1))
    return values


def path_values(work: Path, role: str) -> dict[str, str]:
    """Bad values of a path that a verb reads or writes, by class."""
    bad = work / "bad"
    values = {"a link to nothing": str(bad / "dangling"), "a link loop": str(bad / "loop"),
              "under a file": str(bad / "file.txt" / "x")}
    if role == "reads":
        values.update({"nothing there": str(bad / "nothing"), "an empty file": str(bad / "empty.obj"),
                       "garbage": str(bad / "garbage.json"),
                       "a folder": str(bad / "folder"), "a file": str(bad / "file.txt")})
    else:
        values.update({"a folder real2sim did not make": str(bad / "theirs"),
                       "an overlong name": str(bad / ("n" * 300)), "nowhere to write": "/proc/real2sim_out"})
    return values


def make_bad_files(work: Path) -> None:
    bad = work / "bad"
    bad.mkdir(parents=True, exist_ok=True)
    (bad / "empty.obj").write_bytes(b"")
    (bad / "garbage.json").write_bytes(os.urandom(512))
    (bad / "folder").mkdir(exist_ok=True)
    (bad / "file.txt").write_text("a file")
    (bad / "theirs").mkdir(exist_ok=True)
    (bad / "theirs" / "thesis.tex").write_text("precious")
    for name, target in (("dangling", bad / "nowhere" / "x"), ("loop", bad / "loop")):
        if not os.path.lexists(bad / name):
            os.symlink(target, bad / name)


def substitute(args: list[str], inputs: dict[str, Path], new: Path) -> list[str]:
    out = []
    for arg in args:
        for name, path in inputs.items():
            arg = arg.replace("{" + name + "}", str(path))
        out.append(arg.replace("{new}", str(new)))
    return out


def command(verb: str, parser: argparse.ArgumentParser, action: argparse.Action | None, value: str,
            inputs: dict[str, Path], new: Path) -> list[str]:
    """The valid command of ``verb`` with ``action``'s value replaced by (or given as) ``value``."""
    positionals, opts = (substitute(part, inputs, new) for part in VALID[verb])
    if action is not None and not action.option_strings:
        slots = [a for a in parser._actions if not a.option_strings and a.dest != "help"]
        index = slots.index(action) - (1 if verb == "objects" else 0) + (1 if verb == "objects" else 0)
        while len(positionals) <= index:
            positionals.append(value)
        positionals[index] = value
    elif action is not None:
        flag = next((f for f in action.option_strings if f in opts), None)
        if flag is None:
            opts += [action.option_strings[-1], value]
        else:
            opts[opts.index(flag) + 1] = value
    return [verb, *positionals, *opts]


def cases(work: Path, inputs: dict[str, Path]) -> list[tuple[str, str, str, list[str]]]:
    """(verb, option, class, argv) for every option of every verb."""
    out = []
    for verb, parser in verb_parsers().items():
        if verb not in VALID or verb in SKIP_VERBS:
            continue
        roles = parser.get_default("path_roles") or {}
        for action in parser._actions:
            if action.dest in ("help", "overwrite") or action.nargs == 0:
                continue
            name = action.option_strings[-1] if action.option_strings else action.dest.upper()
            if isinstance(action.type, options.Number):
                values = {f"number {v!r}": v for v in number_values(action.type)}
            elif action.choices:
                values = {"unknown choice": "bogus"}
            elif action.dest in roles:
                values = path_values(work, roles[action.dest][0]) if roles[action.dest][0] in ("reads", "writes") else {}
            else:
                values = {"empty text": "", "nonsense text": "bogus:0"}
            for cls, value in values.items():
                new = work / "out" / f"{verb}_{action.dest}_{len(out)}"
                if cls == "an input inside it":  # the output holds a copy of this input: refused, and kept
                    argv = command(verb, parser, action, str(inputs["inputs_parent"] / "input"), inputs,
                                   inputs["inputs_parent"])
                    argv += ["--overwrite"] if "--overwrite" in parser._option_string_actions else []
                else:
                    argv = command(verb, parser, action, value, inputs, new)
                out.append((verb, name, cls, argv))
    return out


def judge(code: int | None, err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("WARNING")]
    if code is None:
        return "still running"
    if "Traceback" in err or code == 1:
        return "internal error"
    if code == 2:
        return "refused" if len(lines) == 1 else "several lines"
    if code == 0:
        return "accepted"
    return f"exit {code}"


def parse_only(argv: list[str]) -> tuple[int, str] | None:
    """(2, stderr) when the parser itself refuses ``argv`` (in this process: a number or a choice is
    judged where it is parsed), None when it parses and must be run."""
    import contextlib
    import io

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0), err.getvalue()
    return None


def run_case(argv: list[str], limit_s: float, cwd: Path) -> tuple[int | None, str]:
    try:
        done = subprocess.run(REAL2SIM + argv, capture_output=True, text=True, timeout=limit_s, cwd=cwd,
                              env={**os.environ, "REAL2SIM_THREADS": "1"})
        return done.returncode, done.stderr
    except subprocess.TimeoutExpired as exc:
        return None, (exc.stderr or b"").decode() if isinstance(exc.stderr, bytes) else (exc.stderr or "")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--limit-s", type=float, default=60.0)
    ap.add_argument("--work", type=Path, default=None, help="keep the inputs and outputs here")
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="r2s_pass_"))
    work.mkdir(parents=True, exist_ok=True)
    make_bad_files(work)
    inputs: dict[str, Path] = {}
    for name, argv in SETUP.items():
        target = work / name
        if not target.exists():
            if name == "mesh":
                target.mkdir()
            done = subprocess.run(REAL2SIM + [a.replace("OUT", str(target)).replace("WORK", str(work)) for a in argv],
                                  capture_output=True, text=True)
            if done.returncode != 0:
                raise SystemExit(f"setup {name} failed: {done.stderr.strip()}")
        inputs[name] = target
    inputs["dataset_copy"] = work / "dataset"  # in-place verbs: the pass only checks refusals
    parent = work / "inputs_parent"
    parent.mkdir(exist_ok=True)
    (parent / ".real2sim").write_text("{}")
    inputs["inputs_parent"] = parent
    all_cases = cases(work, inputs)
    print(f"{len(all_cases)} cases, {args.jobs} at a time, {args.limit_s:g} s each at most", flush=True)
    results = [parse_only(case[3]) for case in all_cases]  # in this process, one at a time (stderr is global)
    to_run = [i for i, r in enumerate(results) if r is None]
    print(f"{len(all_cases) - len(to_run)} refused or accepted by the parser; {len(to_run)} to run", flush=True)
    with ThreadPoolExecutor(args.jobs) as pool:
        for i, result in zip(to_run, pool.map(lambda i: run_case(all_cases[i][3], args.limit_s, work), to_run)):
            results[i] = result
    verdicts: dict[str, int] = {}
    notable = []
    for (verb, name, cls, argv), (code, err) in zip(all_cases, results):
        verdict = judge(code, err)
        verdicts[verdict] = verdicts.get(verdict, 0) + 1
        if verdict != "refused":
            first = next((line for line in err.splitlines() if line.strip()), "")[:160]
            notable.append([verb, name, cls, verdict, first.replace("|", "\\|")])
    rows = [[k, v] for k, v in sorted(verdicts.items(), key=lambda kv: -kv[1])]
    body = (f"{len(all_cases)} cases over {len({c[0] for c in all_cases})} verbs, one process each, "
            f"{args.limit_s:g} s limit.\n\n" + markdown_table(["verdict", "cases"], rows) +
            "\n\nEvery case not refused, to be read by a person (an accepted value can be legitimate: an "
            "option that takes any text, a path the verb creates):\n\n" +
            markdown_table(["verb", "option", "class", "verdict", "first line on stderr"], notable))
    write_result("reliability_pass", "Reliability pass: bad inputs over every verb and option", body,
                  "python benchmarks/reliability_pass.py " + " ".join(sys.argv[1:]))
    print(json.dumps(verdicts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
