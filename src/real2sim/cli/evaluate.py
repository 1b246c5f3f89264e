"""`real2sim evaluate` (the simulation sweep) and `real2sim report` (rebuild plots and report.html)."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

# Light modules (numpy at most): the vocabulary of --tasks and --contact, defined once.
from real2sim.cli.options import declare_paths, finish, integer, jobs, positive, seed
from real2sim.evaluate.scene.tasks import TASKS
from real2sim.formats.contact import CONTACT_MODELS
from real2sim.formats.results import SIMULATORS


def _csv_list(text: str) -> tuple[str, ...]:
    return tuple(t.strip() for t in text.split(",") if t.strip())


SIMULATOR_HELP = (f"simulator of the candidates: {', '.join(SIMULATORS)} (default drake); repeatable or a comma "
                  "list, both at once allowed. The reference is Drake's hydroelastic simulation of the closed mesh "
                  "either way; MuJoCo simulates each representation's model.xml (asset --format mjcf) with point "
                  "contacts only (docs/evaluation.md)")


def add_simulator_argument(parser) -> None:
    """``--simulator`` (EvaluationConfig.simulators), one flag for evaluate and run --evaluate."""
    parser.add_argument("--simulator", action="append", default=None, metavar="LIST", help=SIMULATOR_HELP)


def simulators_from_args(args: argparse.Namespace) -> tuple[str, ...]:
    """The --simulator values, flattened and in order, repeats dropped; ("drake",) when none given."""
    given = [s for text in (getattr(args, "simulator", None) or ()) for s in _csv_list(text)]
    return tuple(dict.fromkeys(given)) if given else ("drake",)


def register(sub) -> None:
    p = sub.add_parser(
        "evaluate",
        help="simulate every representation of the given assets against the reference mesh; "
        "write runs.csv, summary.csv (Table I layout), Pareto plots and report.html",
        description="Evaluation sweep (paper V-C). For every asset folder, task and run the reference mesh "
        "is simulated once with hydroelastic contact; every representation (each subfolder holding model.urdf) "
        "is then simulated with each contact model from the same initial state and scored: ATE and OCAE (m) "
        "against the reference with equation error (state reset to the reference every 0.1 s), CPD (m/s), and "
        "wall-clock simulation time (s). If RESULTS already holds runs.csv, the sweep resumes: rows without an "
        "error are kept and not simulated again (failed rows are retried); pass --overwrite to start afresh. "
        "RESULTS is replaced only when the sweep completes; progress is kept in .RESULTS.partial meanwhile.",
        epilog="example: real2sim evaluate bottle_asset can_asset --out results --runs 10 --jobs 2",
    )
    p.add_argument("assets", nargs="+", type=Path, metavar="ASSETDIR", help="asset folders made by `real2sim asset`")
    p.add_argument("--out", type=Path, required=True, metavar="RESULTS", help="results folder")
    p.add_argument("--reference", type=Path, metavar="MESH",
                   help="ground-truth mesh (metres) in the frame of the mesh the assets were built from; it is "
                   "moved into each asset's frame with canonical_transform.json (default: each asset's own closed mesh, "
                   "visual/collision_reference.obj, else visual/model.obj)")
    p.add_argument("--reference-inertia", choices=["asset", "mesh"], default="asset",
                   help="mass properties of the reference: the asset's (default, the paper's protocol) or those "
                   "of the --reference mesh itself at the asset's mass (uniform density): a true object "
                   "simulated as it is")
    tasks, contacts = ",".join(TASKS), ",".join(CONTACT_MODELS)
    p.add_argument("--tasks", default=tasks, metavar="LIST",
                   help=f"comma-separated tasks: {', '.join(TASKS)} (default all)")
    p.add_argument("--contact", default=contacts, metavar="LIST",
                   help=f"comma-separated contact models: {', '.join(CONTACT_MODELS)} (default all)")
    add_simulator_argument(p)
    p.add_argument("--runs", type=integer(1, 1000), default=10, metavar="N", help="runs per object and task (default 10, as the paper)")
    p.add_argument("--seed", type=seed(), default=0, help="seed of the runs' initial conditions (default 0)")
    p.add_argument("--jobs", type=jobs, default=None, metavar="N", help="simulations in parallel (default: CPU count); simulation times are measured under this load, "
                   "so use --jobs 1 on an idle machine for timings to publish")
    p.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="local process pool (default) or Ray tasks")
    p.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="Ray cluster to join (default $RAY_ADDRESS, else a local Ray); assets and RESULTS must be "
                   "on a file system the workers share")
    p.add_argument("--simulation-error", action="store_true",
                   help="free roll-outs from the same initial state instead of equation error (no resets)")
    p.add_argument("--duration-scale", type=positive(100.0), default=1.0, metavar="K",
                   help="multiply the push duration and the ramp's total duration by K (default 1; < 1 for quick looks)")
    p.add_argument("--recommend", choices=["accuracy", "speed", "smoothness"], default=None,
                   help="print the recommended representation for this preference (all three are in report.html)")
    p.add_argument("--sim-timeout-s", type=positive(86400.0), default=600.0, metavar="S",
                   help="wall-clock limit of one simulation in seconds (default 600); past it the row is recorded as "
                   "failed with the reason 'timeout' and the sweep goes on")
    p.add_argument("--ray-timeout-s", type=positive(3600.0), default=30.0, metavar="S",
                   help="how long to wait for the Ray cluster to answer, in seconds (default 30)")
    p.add_argument("--no-animations", action="store_true",
                   help="do not write RESULTS/animations/<task>.html (the reference beside the representation "
                   "recommended for accuracy, one run per task; two extra simulations)")
    p.add_argument("--overwrite", action="store_true",
                   help="discard existing results in RESULTS and start afresh (only a folder real2sim made is "
                   "replaced; never an input)")
    p.set_defaults(func=run)
    finish(p)
    declare_paths(p, reads=("assets", "reference"), writes=("out",))

    r = sub.add_parser(
        "report",
        help="rebuild summary.csv, the Pareto plots and report.html from RESULTS/runs.csv",
        description="Rebuild summary.csv, pareto_*.png and the self-contained report.html of a results folder "
        "from its runs.csv (and the protocol recorded in config.json).",
    )
    r.add_argument("results", type=Path, metavar="RESULTS", help="results folder written by `real2sim evaluate`")
    r.set_defaults(func=run_report)
    finish(r)
    declare_paths(r, in_place=("results",))


def config_from_args(args: argparse.Namespace):
    """EvaluationConfig from parsed flags; UserInputError on bad values."""
    import dataclasses
    import math

    from real2sim.plumbing.cores import usable_cores
    from real2sim.plumbing.errors import UserInputError
    from real2sim.evaluate.sweep import EvaluationConfig
    from real2sim.evaluate.scene.scene_config import SceneConfig

    if args.runs < 1:
        raise UserInputError(f"--runs must be >= 1, got {args.runs}")
    if args.ray_address is not None and args.executor != "ray":
        raise UserInputError("--ray-address is for --executor ray")
    if args.jobs is not None and args.jobs < 1:
        raise UserInputError(f"--jobs must be >= 1, got {args.jobs}")
    k = float(args.duration_scale)
    if not (math.isfinite(k) and k > 0):
        raise UserInputError(f"--duration-scale must be a finite number > 0, got {args.duration_scale}")
    scene = SceneConfig()
    if k != 1.0:
        scene = dataclasses.replace(scene, push_duration_s=scene.push_duration_s * k,
                                    total_duration_s=scene.total_duration_s * k)
    return EvaluationConfig(
        tasks=_csv_list(args.tasks), contact_models=_csv_list(args.contact), simulators=simulators_from_args(args),
        runs=args.runs, seed=args.seed,
        jobs=args.jobs or usable_cores(), executor=args.executor, ray_address=args.ray_address,
        simulation_error=args.simulation_error, scene=scene,
        # `real2sim run --evaluate` shares this function but not these flags: the defaults then.
        sim_timeout_s=getattr(args, "sim_timeout_s", 600.0), ray_timeout_s=getattr(args, "ray_timeout_s", 30.0),
    )


def _print_summary(summary, recommend_pref: str | None) -> None:
    from rich.console import Console
    from rich.table import Table

    from real2sim.report.pareto import PREFERENCES, RECOMMENDATION_RULES, recommend
    from real2sim.report.recommend import describe_trade_off, recommend_per_group

    console = Console()
    table = Table(title="summary (means over objects, tasks and runs)")
    for col in ("representation", "OCAE [m]", "ATE [m]", "CPD [m/s]", "ST [s]", "ok/failed"):
        table.add_column(col, justify="left" if col == "representation" else "right")
    for r in summary:
        table.add_row(str(r["representation"]), f"{r['ocae_m']:.4f}", f"{r['ate_m']:.4f}", f"{r['cpd_m_per_s']:.4f}",
                      f"{r['sim_time_s']:.3f}", f"{r['runs_ok']}/{r['runs_failed']}")
    console.print(table)
    for pref in ([recommend_pref] if recommend_pref else PREFERENCES):
        row = recommend(summary, pref)
        name = row["representation"] if row else "(none: no complete rows)"
        console.print(f"recommended for {pref}: [bold]{name}[/bold]  ({RECOMMENDATION_RULES[pref]})")
    preferences = [recommend_pref] if recommend_pref else ["accuracy", "speed"]
    by_group = recommend_per_group(summary, [p for p in preferences if p != "smoothness"] or preferences)
    if len(by_group) > 1:  # one pick per simulator and contact model, each on its own measured front
        for (sim, model), by_pref in by_group.items():
            for pref, row in by_pref.items():
                gives_up = describe_trade_off(row, summary)
                console.print(f"recommended for {pref}, {sim} {model} contact: [bold]{row['representation']}[/bold]"
                              + (f"  (gives up: {gives_up})" if gives_up else ""), highlight=False)


@contextlib.contextmanager
def _reference_properties(args: argparse.Namespace):
    """None (the asset's mass properties), or with ``--reference-inertia mesh`` a temporary
    physical_properties.json of the reference mesh itself (asset frame, the asset's mass)."""
    if args.reference_inertia == "asset":
        yield None
        return
    import json
    import tempfile

    import numpy as np

    from real2sim.asset.inertia import estimate_physical_properties
    from real2sim.plumbing.errors import UserInputError
    from real2sim.geometry.mesh_io import load_mesh
    from real2sim.formats.physical import read_physical_properties, write_physical_properties

    if args.reference is None:
        raise UserInputError("--reference-inertia mesh needs --reference MESH (the mesh whose inertia to use)")
    if len(args.assets) != 1:
        raise UserInputError("--reference-inertia mesh is for one asset (the reference is one object)")
    asset = Path(args.assets[0])
    try:
        mass_kg = read_physical_properties(asset / "physical_properties.json").mass_kg
        transform = np.asarray(json.loads((asset / "canonical_transform.json").read_text())["T_asset_from_input"],
                               dtype=float)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UserInputError(f"{asset} is not a readable asset folder ({type(exc).__name__})") from None
    mesh = load_mesh(args.reference)
    mesh.apply_transform(transform)
    with tempfile.TemporaryDirectory(prefix="real2sim-reference-") as tmp:
        path = Path(tmp) / "reference_physical_properties.json"
        write_physical_properties(estimate_physical_properties(mesh, mass_kg, seed=args.seed), path)
        yield path


def run(args: argparse.Namespace) -> int:
    import os

    from real2sim.cli.progress import progress_display
    from real2sim.evaluate.sweep import evaluate
    from real2sim.evaluate.workdir import partial_dir
    from real2sim.plumbing.errors import UserInputError

    from real2sim.plumbing.outputs import check_output_path

    check_output_path(args.out, what="--out")  # a link to nothing, an overlong name: one line, before any work
    config = config_from_args(args)
    if args.reference is not None and not args.reference.is_file():
        from real2sim.plumbing.paths import missing

        raise UserInputError(f"reference mesh {args.reference} is not a file" if args.reference.exists()
                             else missing(args.reference, "reference mesh"))
    # SIGTERM unwinds as Ctrl-C does (real2sim.cli.main): the sweep ends its workers, keeps its rows.
    # The sweep's messages go to stdout, as they always have; the count of simulations to stderr.
    partial = partial_dir(Path(os.path.abspath(args.out)))
    try:
        with _reference_properties(args) as reference_properties, \
                progress_display(echo=lambda m: print(m, flush=True)) as progress:
            result = evaluate(args.assets, args.out, config, reference_mesh=args.reference, progress=progress,
                              overwrite=args.overwrite, reference_properties=reference_properties,
                              animations=not args.no_animations)
    except KeyboardInterrupt as exc:
        if not partial.is_dir():
            raise
        # the sweep keeps its finished rows on purpose (resumable): say where, instead of a bare "terminated"
        from real2sim.cli import Terminated

        word, code = ("terminated", 143) if isinstance(exc, Terminated) else ("interrupted", 130)
        print(f"real2sim evaluate: {word}; the simulations finished so far are kept in {partial}: run the same "
              "command again to resume", file=sys.stderr)
        return code
    _print_summary(result.summary, args.recommend)
    print(f"{result.simulated} simulations run, {result.skipped} reused, {result.failed} failed; "
          f"results in {result.out_dir} (report: {result.report_path})")
    return 0


def run_report(args: argparse.Namespace) -> int:
    from real2sim.formats.results import read_summary_csv
    from real2sim.report.html import write_report

    path = write_report(args.results, log=lambda m: print(f"real2sim report: {m}", file=sys.stderr, flush=True))
    _print_summary(read_summary_csv(Path(args.results) / "summary.csv"), None)
    print(f"report: {path}")
    return 0
