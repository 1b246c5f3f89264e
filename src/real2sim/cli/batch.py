"""`real2sim batch`: many datasets through `run`, in parallel (local pool or Ray), into one catalogue."""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import sys
from pathlib import Path

from real2sim.cli import options
from real2sim.cli.options import integer, positive

WORKERS = integer(1, 1024)
TIMEOUT_S = positive(3600.0)
MASS_KG = positive(1000.0)
#: run's flags that batch sets per object itself, or does not take
_NOT_FORWARDED = {"dataset", "out", "overwrite", "mass_kg", "help", "frames", "board_square_mm", "board"}


def _run_parser() -> argparse.ArgumentParser:
    from real2sim.cli import OneLineErrorParser
    from real2sim.cli import run as run_cli

    sub = OneLineErrorParser(prog="real2sim").add_subparsers()
    run_cli.register(sub)
    return sub.choices["run"]


def register(sub) -> None:
    p = sub.add_parser(
        "batch",
        help="many datasets through `run` in parallel (local pool or Ray), with a catalogue page",
        description="Run each DATASET through `real2sim run` (same stages, same resumable cache) into "
        "CATALOGUE/<dataset folder name>/, several objects at once, and write CATALOGUE/catalogue.csv, "
        "timings.csv and a self-contained index.html (picture, mass, size, recommended representations, "
        "errors against the truth, stage times, a link to each report; failed objects with their reason). "
        "One object failing never stops the others; running the same command again skips the finished "
        "objects and resumes the others from their last finished stage. Every `real2sim run` option "
        "(see `real2sim run --help`) applies to every object. With --executor ray, DATASETs and CATALOGUE "
        "must be on a folder every node of the cluster reads and writes at the same path.",
        epilog="example: real2sim batch can_ds mug_ds --masses masses.csv --out catalogue --backend hull "
        "--collision spheres:32",
    )
    p.add_argument("datasets", type=Path, nargs="+", metavar="DATASET", help="dataset folders (as `run` takes)")
    p.add_argument("--out", type=Path, required=True, metavar="CATALOGUE",
                   help="catalogue folder: new, or an earlier batch's (resumed)")
    masses = p.add_mutually_exclusive_group()
    masses.add_argument("--masses", type=options.existing_file, metavar="CSV",
                        help="CSV with the columns name,mass_kg (name: the dataset's folder name); a dataset not "
                        "in it is reported as failed")
    masses.add_argument("--mass-from", metavar="NAME.json",
                        help="a JSON file inside each dataset with its mass_kg; a dataset without it is reported "
                        "as failed")
    masses.add_argument("--mass-kg", type=MASS_KG, metavar="KG", help="one mass for every object, kg")
    p.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="local: a process pool on this machine (default); ray: one task per object on a Ray cluster")
    p.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="--executor ray: the cluster (host:port, ray://host:port, or auto); default: a private "
                   "Ray on this machine")
    p.add_argument("--workers", type=WORKERS, default=None, metavar="N",
                   help="objects at once (default: the CPUs, at most the objects)")
    p.add_argument("--ray-timeout-s", type=TIMEOUT_S, default=30.0, metavar="S",
                   help="how long to wait for the Ray cluster at --ray-address, s (default 30)")
    g = p.add_argument_group("`real2sim run` options, for every object")
    for action in _run_parser()._actions:
        if action.dest not in _NOT_FORWARDED:
            g._add_action(action)  # argparse's own way of sharing actions between parsers (parents=)
    options.finish(p)
    options.declare_paths(p, reads=("datasets", "masses", "mask_weights", "properties"), writes=("out",),
                          cache=("sdf_cache",))
    p.set_defaults(func=run)


def read_masses(path: Path) -> dict[str, float]:
    """{name: mass_kg} from a name,mass_kg CSV; UserInputError for a missing column, name or mass, or a
    mass that is not a finite number > 0."""
    from real2sim.plumbing.errors import UserInputError

    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f)
            rows = [(reader.line_num, row) for row in reader]  # the line a row ends on: blank lines are skipped
            columns = reader.fieldnames or []
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise UserInputError(f"cannot read masses file {path}: {exc}") from None
    if "name" not in columns or "mass_kg" not in columns:
        raise UserInputError(f"masses file {path} needs the columns name,mass_kg (has {','.join(columns) or 'none'})")
    others = [column for column in columns if column not in ("name", "mass_kg")]
    if others or len(columns) != 2:  # a third column (or a second mass_kg) would be a setting silently ignored
        extra = ", ".join(repr(c) for c in others) if others else "a column twice"
        raise UserInputError(f"masses file {path}, line 1: the columns are name,mass_kg and nothing else "
                             f"(has {extra})")
    masses: dict[str, float] = {}
    for line, row in rows:
        if None in row:  # csv.DictReader's key for the fields past the header's
            raise UserInputError(f"masses file {path}, line {line}: {len(columns) + len(row[None])} fields, the "
                                 f"header has {len(columns)} (name,mass_kg)")
        name, text = (row.get("name") or "").strip(), (row.get("mass_kg") or "").strip()
        if not name:
            raise UserInputError(f"masses file {path}, line {line}: no name")
        try:
            mass = float(text)
        except ValueError:
            raise UserInputError(f"masses file {path}, line {line}: {name} has no mass "
                                 f"({text!r} is not a number)") from None
        if not (math.isfinite(mass) and 0 < mass <= 1000.0):
            raise UserInputError(f"masses file {path}, line {line}: the mass of {name} must be a number > 0 and "
                                 f"<= 1000 kg (got {text})")
        if name in masses:
            raise UserInputError(f"masses file {path}, line {line}: {name} is listed twice")
        masses[name] = mass
    return masses


def _mass_of(name: str, dataset: Path, args: argparse.Namespace, table: dict[str, float]) -> tuple[float | None, str]:
    """The object's mass, or None and why not (that object fails; the others go on)."""
    if args.mass_kg is not None:
        return args.mass_kg, ""
    if args.masses is not None:
        if name in table:
            return table[name], ""
        return None, f"no mass: {name} is not in {args.masses.name}"
    if args.mass_from is not None:
        path = dataset / args.mass_from
        try:
            value = json.loads(path.read_text()).get("mass_kg")
        except FileNotFoundError:
            return None, f"no mass: the dataset has no {args.mass_from}"
        except (OSError, ValueError, AttributeError):
            return None, f"no mass: {args.mass_from} holds no number mass_kg"
        # float() would take true as 1 kg and "0.3" as a number: only a JSON number is a mass
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            got = json.dumps(value)
            got = got if len(got) <= 40 else got[:40] + "..."
            return None, f"no mass: mass_kg in {args.mass_from} is {got}, not a number"
        try:
            mass = float(value)
        except OverflowError:  # an integer past float's range
            mass = math.inf
        if not (math.isfinite(mass) and 0 < mass <= 1000.0):
            return None, f"no mass: mass_kg in {args.mass_from} must be > 0 and <= 1000 (got {mass:g})"
        return mass, ""
    return None, "no mass: give --mass-kg, --masses or --mass-from"


def check_first(args: argparse.Namespace) -> tuple[list[str], dict[str, float], Path]:
    """The checks that read no dataset: the options, the objects' names, the masses file and CATALOGUE;
    returns (names, masses, CATALOGUE resolved). UserInputError for bad input."""
    from real2sim.plumbing.errors import UserInputError
    from real2sim.pipeline.catalogue import check_catalogue, check_names

    if args.ray_address is not None and args.executor != "ray":
        raise UserInputError("--ray-address is for --executor ray")
    if args.mass_from is not None and (Path(args.mass_from).name != args.mass_from or not args.mass_from):
        raise UserInputError(f"--mass-from names a file inside each dataset, not a path (got {args.mass_from!r})")
    names = check_names(args.datasets)
    table = read_masses(args.masses) if args.masses is not None else {}
    return names, table, check_catalogue(args.out, args.datasets)


def plan(args: argparse.Namespace, first: tuple[list[str], dict[str, float], Path] | None = None):
    """The objects' jobs and the batch's settings; UserInputError for bad input, before anything is written.
    ``first``: what :func:`check_first` returned for ``args``, when it was called already."""
    from dataclasses import replace

    from real2sim.cli.run import config_from_args
    from real2sim.plumbing.errors import UserInputError
    from real2sim.pipeline.batch import BatchConfig, ObjectJob
    from real2sim.pipeline.catalogue import dataset_folder
    from real2sim.plumbing.cores import usable_cores

    names, table, out = first or check_first(args)
    batch = BatchConfig(executor=args.executor, ray_address=args.ray_address, workers=args.workers,
                        ray_timeout_s=args.ray_timeout_s)
    cores = usable_cores()
    workers = max(1, min(args.workers or cores, len(names)))
    # Ray gives a task with one CPU one thread (OMP_NUM_THREADS); numpy's BLAS is held to it as well
    threads = max(1, cores // workers) if args.executor == "local" else 1
    jobs = []
    for name, dataset in zip(names, args.datasets):
        mass, reason = _mass_of(name, dataset_folder(dataset), args, table)
        per = argparse.Namespace(**vars(args))  # config_from_args sets some flags on what it is given
        per.dataset, per.out, per.mass_kg, per.overwrite = Path(dataset), out / name, mass or 1.0, False
        per.frames = per.board_square_mm = per.board = None
        try:
            config = config_from_args(per)  # checks the dataset itself: not a dataset -> one line
        except UserInputError as exc:
            raise UserInputError(f"{dataset}: {exc}") from None
        jobs.append(ObjectJob(name=name, dataset=dataset_folder(dataset), asset_dir=out / name,
                              config=replace(config, asset=replace(config.asset, mass_kg=mass)) if mass else None,
                              reason=reason, threads=threads, gpu=config.device.startswith("cuda"),
                              log=out / ".batch" / f"{name}.log"))
    return jobs, out, batch


def run(args: argparse.Namespace) -> int:
    from real2sim.plumbing.outputs import output_lock

    first = check_first(args)
    out = first[2]
    made = [folder for folder in (out.parent, *out.parent.parents) if not folder.exists()]  # deepest first
    try:
        # before the datasets are read (seconds, torch's import): a second batch on CATALOGUE is refused at once
        with output_lock(out):  # held to the end; run_batch's own lock re-enters it
            return _run_locked(args, first)
    finally:
        if not out.exists():  # refused before anything was written: the folders made for the lock file go too
            for folder in made:
                with contextlib.suppress(OSError):
                    folder.rmdir()


def _run_locked(args: argparse.Namespace, first) -> int:
    from real2sim.cli import Terminated
    from real2sim.cli.progress import progress_display
    from real2sim.pipeline.batch import run_batch

    jobs, out, batch = plan(args, first)

    def echo(line: str) -> None:
        print(line, flush=True)

    try:
        with progress_display(echo=echo) as progress:  # the batch's count; one line per finished object
            result = run_batch(jobs, out, batch, progress=progress, echo=progress_line(progress))
    except KeyboardInterrupt as exc:
        word, code = ("terminated", 143) if isinstance(exc, Terminated) else ("interrupted", 130)
        print(f"real2sim batch: {word}; the finished objects are kept in {out}: run the same command "
              "again to resume", file=sys.stderr)
        return code
    print(f"catalogue: {out / 'index.html'} ({len(jobs) - len(result.failed)} of {len(jobs)} objects done"
          + (f", {len(result.skipped)} finished before" if result.skipped else "") + ")")
    for name in result.failed:
        print(f"  FAILED {name}: {result.outcomes[name].get('reason', '')}")
    return 1 if result.failed else 0


def progress_line(progress):
    """A finished object's line, through the display (above its bar on a terminal)."""
    return lambda line: progress(line, 0, 0)
