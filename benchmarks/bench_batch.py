"""`real2sim batch` throughput: 6 small captures with 1, 2 and 4 workers, local pool and a local Ray.

The 6 captures: the bundled can, mug and bottle, each twice (pose-noise seeds 0 and 1), small views
(the sizes below). Every object: visual hull, 2 representations (spheres:8 and boxes:4), no evaluation,
no pose refinement. Measured, each on a fresh CATALOGUE, as the wall time of the whole command:

* one by one: `real2sim run` on each object, one after another (the baseline a batch replaces);
* `real2sim batch --executor local|ray --workers N` for each N.

Before the timed passes, one object goes through `real2sim run` untimed, so that every pass finds the
libraries (torch, Drake, Open3D: about 2 GB) in the page cache: the first command after a while reads them
from disk, which made one worker's time vary from 70 to 103 s on the same idle machine. With
``--repeats R`` the passes run R times, interleaved, and the median is reported beside every time.

Reported: objects per hour, speed-up against one worker of the same executor, overhead of the
one-worker local batch against one by one, Ray against the local pool with the same workers, and the
mean stage times (from timings.csv), which docs/design-notes/pipeline.md#what-a-batch-costs turns into the
cost of a 100-object batch.

    python benchmarks/bench_batch.py                       # 6 captures, 1 2 4 workers, local and ray
    python benchmarks/bench_batch.py --workers 1 2 --executors local   # what a loaded machine allows
    python benchmarks/bench_batch.py --calibrate            # what two processes get from this machine's cores

``--calibrate`` measures the machine rather than real2sim: one fixed single-threaded job (numpy work of
the sizes the pipeline's stages use, and Python loops) run alone, then two copies at once, each in its
own process; the two copies' throughput against one is the most any two workers can get here.

Writes benchmarks/results/batch.md (machine and date included).
"""

from __future__ import annotations

import argparse
import csv
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import markdown_table, write_result  # noqa: E402

OBJECTS = ("can", "mug", "bottle")
SEEDS = (0, 1)
RUN_FLAGS = ["--backend", "hull", "--voxels", "64", "--max-faces", "5000", "--texture-px", "128",
             "--iterations", "200", "--no-refine-poses", "--collision", "spheres:8", "--collision", "boxes:4"]
MASSES_KG = {"can": 0.35, "mug": 0.3, "bottle": 0.6}


def _cli(*argv) -> float:
    """Wall seconds of ``real2sim ARGV`` in its own process; raises when it fails."""
    return _cli_timed(*argv)[0]


def _cli_timed(*argv) -> tuple[float, float]:
    """Wall and CPU seconds (user + system, its whole process tree) of ``real2sim ARGV``."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "real2sim", *map(str, argv)], capture_output=True, text=True)
    wall_s = time.monotonic() - start
    if done.returncode != 0:
        raise SystemExit(f"real2sim {' '.join(map(str, argv[:2]))} failed:\n{done.stdout}\n{done.stderr}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall_s, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def make_captures(root: Path, views: int, width: int, height: int) -> list[Path]:
    datasets = []
    for name in OBJECTS:
        for seed in SEEDS:
            ds = root / f"{name}_{seed}"
            _cli("capture", name, "--out", ds, "--views", views, "--width-px", width, "--height-px", height, "--seed", seed)
            datasets.append(ds)
    return datasets


def _masses(root: Path, datasets: list[Path]) -> Path:
    path = root / "masses.csv"
    path.write_text("name,mass_kg\n" + "".join(f"{d.name},{MASSES_KG[d.name.split('_')[0]]}\n" for d in datasets))
    return path


def stage_means(catalogue: Path) -> dict[str, float]:
    with open(catalogue / "timings.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    stages: dict[str, list[float]] = {}
    for row in rows:
        stages.setdefault(row["stage"], []).append(float(row["wall_s"]))
    return {stage: statistics.mean(values) for stage, values in stages.items()}


def passes(executors: list[str], workers: list[int], serial: bool) -> list[tuple[str, int]]:
    """The order the passes run in: the pool's 1 and 2 workers and Ray's 2 first (the issue's targets),
    then one by one, then the rest; each pass's numbers are written as soon as it ends."""
    wanted = [(e, w) for e in executors for w in workers] + ([("one by one", 1)] if serial else [])
    first = [p for p in (("local", 1), ("local", 2), ("ray", 2), ("one by one", 1)) if p in wanted]
    return first + [p for p in wanted if p not in first]


def report(timings: dict, n: int, means: dict, args, views: str) -> None:
    """``timings``: (executor, workers) -> [(wall s, CPU s) per repeat]; the medians make the table."""
    results = {key: statistics.median(w for w, _ in runs) for key, runs in timings.items()}
    rows = []
    serial_s = results.get(("one by one", 1))
    for (executor, workers), wall_s in results.items():
        if executor == "one by one":
            continue
        one = results.get((executor, 1))
        local = results.get(("local", workers))
        runs = timings[executor, workers]
        rows.append([executor, workers, round(wall_s), " ".join(f"{w:.0f}" for w, _ in runs),
                     # Ray's workers are its daemons' children, not the command's: their CPU is not counted
                     round(statistics.median(c for _, c in runs)) if executor != "ray" else "-",
                     round(n * 3600 / wall_s, 1),
                     f"{one / wall_s:.2f}x" if one else "-",
                     f"{100 * (wall_s / local - 1):+.0f} %" if local and executor == "ray" else "-"])
    body = [f"{n} captures ({views}), `{' '.join(RUN_FLAGS)}`, no evaluation; each row a fresh CATALOGUE, the "
            "whole command's wall time (Ray's start included); the libraries warmed into the page cache first; "
            f"{args.repeats} repeat(s) interleaved, medians (each repeat's wall time beside them; CPU: user + "
            "system seconds of the whole process tree).", "",
            markdown_table(["executor", "workers", "wall s (median)", "each repeat s", "CPU s", "objects / h",
                            "vs 1 worker", "vs local pool"], rows)]
    if serial_s is not None:
        body += ["", f"One by one (`real2sim run` x {n}): {serial_s:.0f} s, {n * 3600 / serial_s:.1f} objects / h."]
        if ("local", 1) in results:
            body.append(f"Overhead of the one-worker local batch against one by one: "
                        f"{100 * (results['local', 1] / serial_s - 1):+.0f} %.")
    if means:
        body += ["", "Mean stage times per object (timings.csv of the first batch): "
                 + ", ".join(f"{s} {t:.1f} s" for s, t in means.items()) + "."]
    command = "python benchmarks/bench_batch.py " + " ".join(sys.argv[1:])
    path = write_result(args.tag, "real2sim batch: throughput with workers (issue 31)", "\n".join(body), command)
    print("\n".join(body))
    print(f"wrote {path}", flush=True)


CALIBRATION_JOB = """
import time, numpy as np
from threadpoolctl import threadpool_limits
rng = np.random.default_rng(0)
a, pts = rng.random((256, 256)), rng.random((200_000, 3))
start = time.process_time()
with threadpool_limits(1):
    for _ in range(ROUNDS):
        b = a @ a
        d = np.sqrt(((pts[:, None, :] - pts[:64][None]) ** 2).sum(-1)).min(1)
        total = sum(i * i for i in range(200_000))
print(time.process_time() - start)
"""


def calibrate(rounds: int, repeats: int) -> None:
    """Wall and CPU seconds of CALIBRATION_JOB alone and two copies at once; writes batch_calibration.md."""
    job = CALIBRATION_JOB.replace("ROUNDS", str(rounds))
    rows = []
    for repeat in range(repeats):
        for copies in (1, 2):
            start = time.monotonic()
            procs = [subprocess.Popen([sys.executable, "-c", job], stdout=subprocess.PIPE, text=True)
                     for _ in range(copies)]
            cpu_s = [float(p.communicate()[0]) for p in procs]
            wall_s = time.monotonic() - start
            rows.append([repeat + 1, copies, round(wall_s, 2), " ".join(f"{c:.2f}" for c in cpu_s)])
            print(rows[-1], flush=True)
    alone = statistics.median(r[2] for r in rows if r[1] == 1)
    both = statistics.median(r[2] for r in rows if r[1] == 2)
    body = (f"One single-threaded job (`CALIBRATION_JOB`, {rounds} rounds of a 256x256 matrix product, distances of "
            "200,000 points to 64 and a Python loop), alone and as two processes at once; each row's wall seconds "
            "(both copies, start to the last one's end) and each copy's CPU seconds.\n\n"
            + markdown_table(["repeat", "copies", "wall s", "CPU s of each"], rows)
            + f"\n\nMedians: alone {alone:.2f} s, two at once {both:.2f} s: two processes do "
            f"{2 * alone / both:.2f}x the work of one in the same time on this machine (2.00x: two free cores).")
    path = write_result("batch_calibration", "real2sim batch: what two processes get from this machine",
                         body, "python benchmarks/bench_batch.py " + " ".join(sys.argv[1:]))
    print(body)
    print(f"wrote {path}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calibrate", action="store_true",
                        help="measure two single-threaded processes against one (this machine, not real2sim)")
    parser.add_argument("--calibrate-rounds", type=int, default=20)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--executors", nargs="+", default=["local", "ray"], choices=["local", "ray"])
    parser.add_argument("--views", type=int, default=24)
    parser.add_argument("--width", type=int, default=160)
    parser.add_argument("--height", type=int, default=120)
    parser.add_argument("--no-serial", action="store_true", help="skip the one-by-one baseline")
    parser.add_argument("--tag", default="batch", help="section name in benchmarks/results/")
    parser.add_argument("--repeats", type=int, default=1, help="run every pass this many times, interleaved")
    args = parser.parse_args()
    if args.calibrate:
        calibrate(args.calibrate_rounds, args.repeats)
        return
    views = (f"{', '.join(OBJECTS)} x seeds {SEEDS}; {args.views} views at {args.width}x{args.height}")

    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        root = Path(tmp)
        datasets = make_captures(root, args.views, args.width, args.height)
        masses = _masses(root, datasets)
        first = datasets[0]
        _cli("run", first, "--mass-kg", MASSES_KG[first.name.split("_")[0]], "--out", root / "warm_up", *RUN_FLAGS)
        timings: dict[tuple[str, int], list[tuple[float, float]]] = {}
        means: dict[str, float] = {}
        for repeat in range(args.repeats):
            for executor, workers in passes(args.executors, args.workers, not args.no_serial):
                if executor == "one by one":
                    serial = [_cli_timed("run", ds, "--mass-kg", MASSES_KG[ds.name.split("_")[0]], "--out",
                                         root / f"serial_{repeat}" / ds.name, *RUN_FLAGS) for ds in datasets]
                    wall_cpu = (sum(w for w, _ in serial), sum(c for _, c in serial))
                else:
                    out = root / f"{executor}_{workers}_{repeat}"
                    wall_cpu = _cli_timed("batch", *datasets, "--masses", masses, "--out", out,
                                          "--executor", executor, "--workers", workers, *RUN_FLAGS)
                    means = means or stage_means(out)
                    shutil.rmtree(out, ignore_errors=True)
                timings.setdefault((executor, workers), []).append(wall_cpu)
                print(f"repeat {repeat + 1}: {executor} x{workers}: {wall_cpu[0]:.0f} s wall, {wall_cpu[1]:.0f} s CPU",
                      flush=True)
                report(timings, len(datasets), means, args, views)


if __name__ == "__main__":
    main()
