"""Where the whole job's time goes: wall and CPU seconds per stage and per phase inside each stage.

    python benchmarks/bench_profile.py [--demo full|quick|none] [--phone VIEWS|0] [--before REV] [--note TEXT]

Runs the demo's job (a simulated robot capture of the bundled bottle -> run -> evaluate, as
`real2sim demo` does) and a handheld phone capture of the bundled mug through `run` (with the
printed board, fitting `run`'s default collision SPEC; ``--phone-collision cylinders:10 coacd`` adds CoACD,
whose decomposition of a reconstructed mug takes longer than the rest of the asset stage), in this process, with a progress function that timestamps every report. A phase is
what a stage reports while it works ("reconstruct / training field", "asset / collision
cylinders:10 ..."); the time between two reports belongs to the later one's phase, since a report
says what the work before it was. CPU seconds are this process's and all its children's (live and
finished), so the simulation workers count. Nothing is instrumented: the profile sees what a user's
progress display sees, at most one sample every 0.2 s per phase.

With ``--before REV`` (a git revision, e.g. the last release or ``HEAD~3``) each job runs twice, back to
back on the same machine (the same job, as this script defines it), first with the package of REV (a temporary git worktree put first on
``PYTHONPATH``), then with this tree's, each in a fresh process, and the tables give both side by side,
so that a speed-up is read against the code before it under the same conditions.

Writes benchmarks/results/profile.md and .json (profile_TAG with ``--tag``; see common.py).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import markdown_table, write_result  # noqa: E402

#: Seconds between two samples of one phase (a phase's end is always sampled).
SAMPLE_S = 0.2


def cpu_seconds(proc: psutil.Process) -> float:
    """User + system seconds of ``proc``, its finished children and its live descendants."""
    t = proc.cpu_times()
    total = t.user + t.system + t.children_user + t.children_system
    for child in proc.children(recursive=True):
        try:
            c = child.cpu_times()
            total += c.user + c.system
        except psutil.Error:
            pass  # gone between listing and reading: its time is in children_* now
    return total


def phase_of(message: str) -> tuple[str, str]:
    """(stage, phase) of a progress message: "[3/7] reconstruct - training field 12/400" ->
    ("reconstruct", "training field #/#")."""
    stage, _, rest = message.partition(" - ")
    stage = re.sub(r"^\[\d+/\d+\]\s*", "", stage).split(":")[0].strip()
    if not rest:
        stage_name, _, rest = message.partition(": ")
        stage = re.sub(r"^\[\d+/\d+\]\s*", "", stage_name).strip() or stage
    rest = rest.split(", ")[0]
    rest = re.sub(r"\d+(\.\d+)?", "#", rest)
    return stage, rest[:70].strip()


@dataclass
class Profile:
    """Wall and CPU seconds by (stage, phase), in the order phases first appeared."""

    wall: dict = field(default_factory=dict)
    cpu: dict = field(default_factory=dict)
    start_wall: float = 0.0
    start_cpu: float = 0.0
    last: tuple = ("", "", 0.0, 0.0)  # phase key, wall, cpu of the last sample

    def __post_init__(self):
        self.proc = psutil.Process()
        self.start_wall, self.start_cpu = time.perf_counter(), cpu_seconds(self.proc)
        self.last = (("start", "start"), self.start_wall, self.start_cpu)

    def __call__(self, message: str, done: int, total: int) -> None:
        key = phase_of(message)
        now = time.perf_counter()
        if key == self.last[0] and now - self.last[1] < SAMPLE_S and not (total and done == total):
            return
        cpu = cpu_seconds(self.proc)
        self.wall[key] = self.wall.get(key, 0.0) + now - self.last[1]
        self.cpu[key] = self.cpu.get(key, 0.0) + cpu - self.last[2]
        self.last = (key, now, cpu)
        if total == 0:
            print(f"{now - self.start_wall:7.1f} s  {message}", flush=True)

    def close(self) -> None:
        self("[end] end - end", 0, 0)

    def rows(self) -> list[list]:
        """Per stage: its total, then its phases of at least 1 % of the job's wall time."""
        total_wall = sum(self.wall.values()) or 1.0
        stages: dict[str, list] = {}
        for key in self.wall:
            stages.setdefault(key[0], []).append(key)
        out = []
        for stage, keys in stages.items():
            wall, cpu = sum(self.wall[k] for k in keys), sum(self.cpu[k] for k in keys)
            out.append([f"**{stage}**", "", wall, cpu, 100 * wall / total_wall])
            for k in sorted(keys, key=lambda k: -self.wall[k]):
                if self.wall[k] >= 0.01 * total_wall and len(keys) > 1:
                    out.append(["", k[1], self.wall[k], self.cpu[k], 100 * self.wall[k] / total_wall])
        out.append(["**total**", "", total_wall, sum(self.cpu.values()), 100.0])
        return out


def profile_demo(work: Path, quick: bool) -> Profile:
    """The demo's job (cli/demo.py's plan) under a profiling progress function."""
    from real2sim.capture.sim.wrist_camera import capture
    from real2sim.cli.demo import FULL, QUICK, capture_config, run_config
    from real2sim.evaluate.sweep import EvaluationConfig
    from real2sim.geometry.objects import make_textured_object
    from real2sim.pipeline.run import run_pipeline
    from real2sim.plumbing.progress import prefixed

    plan = QUICK if quick else FULL
    prof = Profile()
    capture(make_textured_object("bottle"), work / "capture", capture_config(plan), progress=prefixed(prof, "capture"))
    evaluation = EvaluationConfig(tasks=plan.tasks, contact_models=plan.contact_models, runs=plan.runs)
    run_pipeline(work / "capture", work / "bottle_asset", replace(run_config(plan), evaluation=evaluation),
                 progress=prof)
    prof.close()
    return prof


#: The phone job's collision SPECs: `run`'s default (``--phone-collision`` adds others, CoACD say).
PHONE_COLLISION = ("cylinders:10",)


def profile_phone(work: Path, views: int, specs: tuple[str, ...] = PHONE_COLLISION) -> Profile:
    """A handheld capture of the bundled mug with the board, then `run` over its photos, fitting ``specs``."""
    from real2sim.asset.config import AssetConfig
    from real2sim.capture.phone.board import DEFAULT_BOARD
    from real2sim.capture.sim.handheld import HandheldConfig, capture_handheld
    from real2sim.formats.spec import parse_spec
    from real2sim.geometry.objects import OBJECTS, make_textured_object
    from real2sim.pipeline.run import RunConfig, run_pipeline
    from real2sim.plumbing.progress import prefixed

    prof = Profile()
    capture_handheld(make_textured_object("mug"), work / "photos", HandheldConfig(views=views, board=DEFAULT_BOARD),
                     progress=prefixed(prof, "capture"))
    asset = AssetConfig(mass_kg=OBJECTS["mug"].mass_kg, specs=tuple(parse_spec(s) for s in specs))
    run_pipeline(work / "photos", work / "mug_asset", RunConfig(asset=asset), progress=prof)
    prof.close()
    return prof


def profile_rows(job: str, arg: str, work: Path) -> dict:
    """One job ("demo" with "full"/"quick", or "phone" with its photo count and SPECs, space-separated): its
    profile rows, and its reconstruction against the truth (truth.json: Chamfer mm, IoU)."""
    if job == "demo":
        prof, asset = profile_demo(work / "demo", arg == "quick"), work / "demo" / "bottle_asset"
    else:
        views, *specs = arg.split()
        prof, asset = profile_phone(work / "phone", int(views), tuple(specs) or PHONE_COLLISION), work / "phone" / "mug_asset"
    truth = json.loads((asset / "truth.json").read_text()).get("reconstruction", {})
    return {"rows": prof.rows(), "chamfer_mm": truth.get("chamfer_mm"), "iou": truth.get("iou")}


def rows_in_process(job: str, arg: str, src: Path | None, work: Path) -> dict:
    """:func:`profile_rows` in a fresh process, with the package at ``src`` (None: this tree's)."""
    out = work / f"{job}_rows.json"
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(src), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    subprocess.run([sys.executable, __file__, "--rows-only", job, arg, str(out)], env=env, check=True)
    return json.loads(out.read_text())


def quality_line(runs: list[tuple[str, dict]]) -> str:
    """The reconstruction's figures against the truth of each run (label, :func:`profile_rows`' record)."""
    return "Reconstruction against the truth: " + "; ".join(
        f"{label}{' ' * bool(label)}Chamfer {r['chamfer_mm']:.3f} mm, IoU {r['iou']:.3f}" if r.get("chamfer_mm") is not None
        else f"{label}{' ' * bool(label)}no truth" for label, r in runs) + "."


def _by_stage(rows: list[list]) -> dict[str, list[list]]:
    """Profile rows grouped under their stage's row (a phase row's stage cell is empty)."""
    stages: dict[str, list[list]] = {}
    stage = ""
    for row in rows:
        if row[0]:
            stage = row[0]
        stages.setdefault(stage, []).append(row)
    return stages


def side_by_side(before: list[list], after: list[list]) -> list[list]:
    """Rows (stage, phase, wall before, wall now, CPU before, CPU now): each stage's row, then its phases,
    matched by (stage, phase); stages and phases in the order of ``after``, then those only ``before`` had.
    A phase under 1 % of a job's wall time is left out of its rows (:meth:`Profile.rows`), so a cell is
    blank where one run had it above that and the other below."""
    old, new = _by_stage(before), _by_stage(after)
    out = []
    for stage in list(new) + [s for s in old if s not in new]:
        b_rows = {r[1]: r for r in old.get(stage, [])}
        a_rows = {r[1]: r for r in new.get(stage, [])}
        for phase in list(a_rows) + [p for p in b_rows if p not in a_rows]:
            b, a = b_rows.get(phase), a_rows.get(phase)
            out.append([stage if phase == "" else "", phase, b[2] if b else "", a[2] if a else "",
                        b[3] if b else "", a[3] if a else ""])
    total = [r for r in out if r[0] == "**total**"]
    return [r for r in out if r[0] != "**total**"] + total


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--demo", choices=["full", "quick", "none"], default="full")
    parser.add_argument("--phone", type=int, default=60, metavar="VIEWS", help="photos of the phone capture (0: none)")
    parser.add_argument("--phone-collision", nargs="+", default=list(PHONE_COLLISION), metavar="SPEC",
                        help="the phone job's collision SPECs (default: run's, %(default)s)")
    parser.add_argument("--before", metavar="REV", help="also profile git revision REV first, and show both")
    parser.add_argument("--note", default="", help="a line about the conditions (e.g. a machine shared with other work)")
    parser.add_argument("--tag", default="", help="write profile_TAG instead of profile (e.g. the phone job alone)")
    parser.add_argument("--rows-only", nargs=3, metavar=("JOB", "ARG", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.rows_only:
        job, arg, out = args.rows_only
        with tempfile.TemporaryDirectory(prefix="bench_profile-") as tmp:
            Path(out).write_text(json.dumps(profile_rows(job, arg, Path(tmp))))
        return 0
    jobs = ([("demo", args.demo, f"The demo's job ({args.demo})")] if args.demo != "none" else []) + (
        [("phone", " ".join([str(args.phone), *args.phone_collision]),
          f"A {args.phone}-photo phone capture of the mug through `run` (collision {' '.join(args.phone_collision)})")]
        if args.phone else [])
    header = ["stage", "phase", "wall s", "CPU s", "% of wall"]
    parts = [args.note] if args.note else []
    repo = Path(__file__).resolve().parent.parent
    with tempfile.TemporaryDirectory(prefix="bench_profile-") as tmp:
        tmp = Path(tmp)
        before_src = None
        if args.before:
            rev = subprocess.run(["git", "rev-parse", "--short", args.before], cwd=repo, check=True,
                                 capture_output=True, text=True).stdout.strip()
            subprocess.run(["git", "worktree", "add", "--detach", str(tmp / "before"), rev], cwd=repo, check=True,
                           capture_output=True)
            before_src = tmp / "before" / "src"
            head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=repo, check=True, capture_output=True,
                                  text=True).stdout.strip()
            dirty = subprocess.run(["git", "status", "--porcelain", "--", "src"], cwd=repo, check=True,
                                   capture_output=True, text=True).stdout.strip()
            parts.append(f"Before: {rev}; now: {head}{' with uncommitted changes' if dirty else ''}. Each job ran "
                         "twice back to back on this machine, the revision before first.")
        try:
            for job, arg, title in jobs:
                if before_src is None:
                    now = rows_in_process(job, arg, None, tmp)
                    parts += [f"### {title}", markdown_table(header, now["rows"]), quality_line([("", now)])]
                    continue
                before = rows_in_process(job, arg, before_src, tmp)
                after = rows_in_process(job, arg, None, tmp)
                parts += [f"### {title}", markdown_table(
                    ["stage", "phase", "wall s before", "wall s now", "CPU s before", "CPU s now"],
                    side_by_side(before["rows"], after["rows"])), quality_line([("before", before), ("now", after)])]
        finally:
            if before_src is not None:
                subprocess.run(["git", "worktree", "remove", "--force", str(tmp / "before")], cwd=repo,
                               capture_output=True)
    print(write_result("profile" + (f"_{args.tag}" if args.tag else ""), "Profile: wall and CPU seconds per stage and phase", "\n\n".join(parts),
                        "python benchmarks/bench_profile.py " + " ".join(sys.argv[1:])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
