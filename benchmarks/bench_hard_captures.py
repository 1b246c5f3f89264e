"""`real2sim run` on hard captures (issue #28, "Targets"): each hard-rig condition of `capture` alone,
and all of them together, on the bundled bottle and can, judged against the truth.

For each object and condition: `real2sim capture OBJECT --views N --width-px 320 --height-px 240 FLAGS`
(robot poses with the default 5 mm / 1 deg noise), then `real2sim run DATASET --mass-kg KG --out ASSET`
with the default settings (radiance field backend), both as a user would type them. Reported from
ASSET/truth.json: the reconstruction's Chamfer distance (mm) and volume IoU against the true object,
whether the issue's target holds (Chamfer <= 1.5 mm and IoU >= 0.90), the WARNING lines `run` printed,
and the wall seconds of `run`. A run that fails is a row too, with its last error line.

    python benchmarks/bench_hard_captures.py                   # bottle and can, every condition (hours on 2 cores)
    python benchmarks/bench_hard_captures.py --objects can --conditions no_table,all
    python benchmarks/bench_hard_captures.py --quick           # the can, all conditions together, tiny: minutes
    python benchmarks/bench_hard_captures.py --objects can --conditions jitter --tag jitter   # its own section file
    python benchmarks/bench_hard_captures.py --objects can --prepare DIR      # captures + refine-poses only, then
    python benchmarks/bench_hard_captures.py --objects can --datasets DIR --device cuda --tag cuda   # on a GPU box
    python benchmarks/bench_hard_captures.py --objects can --conditions low_res_256x192 --views 60 --all-unrefined

--all-unrefined puts every view in the state refine-poses leaves when COLMAP registers too few frames
(each frame marked not refined, the given noisy poses kept) and runs `run --no-refine-poses`: what the
reconstruction does when COLMAP cannot refine (issue #28's 60-view 256x192 target), whatever COLMAP
would have managed on this capture. Its rows go to benchmarks/results/hard_captures_unrefined.md.

--quick is a smoke test of the script, not of the targets: 16 views at 128x96 and `run --steps 300
--voxels 64`. Writes benchmarks/results/hard_captures.md (machine, date, command) after each row.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from common import markdown_table, write_result  # noqa: E402

TARGET_CHAMFER_MM = 1.5
TARGET_IOU = 0.90

#: Each hard condition as `capture` flags; the long lens is fx = 3300 px at 640x480 (real turntable
#: rigs), scaled to the capture's width by :func:`_flags`. "all" is every condition at once.
CONDITIONS: dict[str, list[str]] = {
    "default": [],
    "ring_level": ["--ring-elevation-deg", "0"],
    "ring_20deg": ["--ring-elevation-deg", "20"],
    "long_lens": ["--focal-px", "LONG_LENS"],
    "cut_off": ["--cut-off-fraction", "0.25"],
    "no_table": ["--no-table"],
    "jitter": ["--exposure-jitter-stops", "0.5", "--white-balance-jitter", "0.1"],
    "jpeg": ["--jpeg", "--jpeg-quality", "85"],
    "low_res_256x192": ["--width-px", "256", "--height-px", "192"],
    "all": ["--ring-elevation-deg", "0", "--focal-px", "LONG_LENS", "--cut-off-fraction", "0.25", "--no-table",
            "--exposure-jitter-stops", "0.5", "--white-balance-jitter", "0.1", "--jpeg", "--jpeg-quality", "85"],
}
LONG_LENS_PX_AT_640 = 3300.0


def _flags(condition: str, width: int, height: int) -> list[str]:
    """The capture's flags for ``condition`` at ``width`` x ``height`` px (a condition may set its own size)."""
    flags = [f if f != "LONG_LENS" else f"{LONG_LENS_PX_AT_640 * width / 640:g}" for f in CONDITIONS[condition]]
    if "--width-px" not in flags:
        flags = ["--width-px", str(width), "--height-px", str(height)] + flags
    return flags


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "real2sim", *args]


def _last_error(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return (lines[-1] if lines else "no output")[:160].replace("|", "/")


def mark_all_unrefined(dataset: Path) -> None:
    """Every frame of ``dataset/transforms.json`` marked as refine-poses marks them when COLMAP refines none."""
    from real2sim.formats.dataset import POSE_REFINED_KEY

    path = dataset / "transforms.json"
    data = json.loads(path.read_text())
    for frame in data["frames"]:
        frame[POSE_REFINED_KEY] = False
    path.write_text(json.dumps(data, indent=2))


def _capture(name: str, condition: str, dataset: Path, views: int, width: int, height: int,
             noise: tuple[float, float], seed: int = 0) -> str:
    """`capture` of ``name`` under ``condition`` into ``dataset`` (``seed``: the capture's pose noise, cut-off
    views and colour jitter); "" or the failure's one line."""
    cap = subprocess.run(_cli("capture", name, "--out", str(dataset), "--views", str(views), "--pose-noise-mm",
                              f"{noise[0]:g}", "--pose-noise-deg", f"{noise[1]:g}", "--seed", str(seed),
                              *_flags(condition, width, height)),
                         capture_output=True, text=True)
    return "" if cap.returncode == 0 else f"capture failed: {_last_error(cap.stderr)}"


def prepare(names: list[str], conditions: list[str], out: Path, views: int, width: int, height: int,
            noise: tuple[float, float]) -> None:
    """Capture each object under each condition into ``out/<name>_<condition>`` and refine its poses as
    `run` does (`refine-poses`): what ``--datasets`` reconstructs on a machine without Drake or COLMAP."""
    for name in names:
        for condition in conditions:
            dataset = out / f"{name}_{condition}"
            failed = _capture(name, condition, dataset, views, width, height, noise)
            if not failed:
                ref = subprocess.run(_cli("refine-poses", str(dataset)), capture_output=True, text=True)
                failed = "" if ref.returncode == 0 else f"refine-poses failed: {_last_error(ref.stderr)}"
            print(f"{dataset}: {failed or 'captured and refined'}", flush=True)


def reconstruct_condition(name: str, condition: str, dataset: Path, device: str) -> list:
    """One table row from a dataset made by :func:`prepare`: `run`'s reconstruction (its defaults) on
    ``device``, judged against the dataset's ground_truth/ (the same figures as truth.json's)."""
    import warnings

    from real2sim.reconstruct.stage import ReconstructConfig, reconstruct

    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = reconstruct(dataset, ReconstructConfig(), device=device, seed=0)
    wall_s = time.perf_counter() - start
    said = sorted({" ".join(str(w.message).split()) for w in caught if issubclass(w.category, RuntimeWarning)
                   and "invalid value encountered" not in str(w.message)})
    rec = result.report["truth"]
    met = rec["chamfer_mm"] <= TARGET_CHAMFER_MM and rec["iou"] >= TARGET_IOU
    return [name, condition, rec["chamfer_mm"], rec["iou"], "yes" if met else "no",
            "; ".join("WARNING: " + w[:100].replace("|", "/") for w in said) or "-", round(wall_s)]


def shape_error(mesh_path: Path, dataset: Path) -> tuple[float, float, float]:
    """The reconstruction's mesh (world frame) against the true object after the translation that best lays
    it on the truth (nearest points, 40 rounds): (Chamfer mm, IoU, that translation's length mm). Apart from
    the world frame: with every pose off, where the object stands in the world is only as sure as the
    poses' mean, which the images cannot fix."""
    import numpy as np
    import trimesh
    from scipy.spatial import cKDTree

    from real2sim.reconstruct.truth import compare_to_truth, load_truth

    truth = load_truth(dataset)
    mesh = trimesh.load(mesh_path, force="mesh")
    rng = np.random.default_rng(0)
    true_points = trimesh.sample.sample_surface(truth, 30000, seed=rng)[0]
    points = trimesh.sample.sample_surface(mesh, 30000, seed=rng)[0]
    tree, shift = cKDTree(true_points), np.zeros(3)
    for _ in range(40):
        _, nearest = tree.query(points + shift)
        shift += (true_points[nearest] - (points + shift)).mean(axis=0)
    moved = mesh.copy()
    moved.apply_translation(shift)
    rec = compare_to_truth(moved, truth)
    return round(rec["chamfer_mm"], 3), round(rec["iou"], 4), round(1000.0 * float(np.linalg.norm(shift)), 2)


def frame_bound(dataset: Path, noise: tuple[float, float], trials: int = 200) -> dict:
    """How far the views' common point (``silhouette_poses.common_point``, from the true masks) lands from
    where the true poses put it, over ``trials`` draws of the capture's pose noise (``perturb_poses``): with
    every pose off, that is how well the given poses place the object in the world, whatever aligns the views
    to each other afterwards. mm: RMS per world axis, median and 90th percentile of the 3-D distance."""
    from dataclasses import replace

    import numpy as np

    from real2sim.capture.sim.wrist_camera import perturb_poses
    from real2sim.formats.dataset import read_ground_truth
    from real2sim.reconstruct.poses.centring import common_point, mask_centres
    from real2sim.multiview.views import load_views

    views = load_views(dataset)
    truth = read_ground_truth(dataset)
    true = dict(zip((f.file_path for f in truth.frames), truth.poses_c2w_cv()))
    true_c2w = np.stack([true[n] for n in views.names])
    centres, whole, _ = mask_centres(views)
    exact, _ = common_point(replace(views, c2w_cv=true_c2w), centres, whole)
    errors = np.array([common_point(replace(views, c2w_cv=perturb_poses(true_c2w, *noise, seed=1000 + t)),
                                    centres, whole)[0] - exact for t in range(trials)]) * 1000.0
    distance = np.linalg.norm(errors, axis=1)
    return {"rms_per_axis_mm": [round(float(x), 2) for x in np.sqrt((errors ** 2).mean(axis=0))],
            "median_mm": round(float(np.median(distance)), 2), "p90_mm": round(float(np.quantile(distance, 0.9)), 2)}


def run_condition(name: str, condition: str, work: Path, views: int, width: int, height: int,
                  run_args: list[str], noise: tuple[float, float] = (5.0, 1.0), all_unrefined: bool = False,
                  seed: int = 0) -> list:
    """One table row: object, condition, capture seed, Chamfer mm, IoU, target met, shape, frame, WARNING
    lines, run seconds."""
    from real2sim.geometry.objects import OBJECTS

    stem = f"{name}_{condition}" + (f"_seed{seed}" if seed else "")
    dataset, asset = work / stem, work / f"{stem}_asset"
    failed = _capture(name, condition, dataset, views, width, height, noise, seed)
    if failed:
        return [name, condition, seed, "-", "-", failed, "-", "-", "-", "-", "-", "-"]
    if all_unrefined:
        mark_all_unrefined(dataset)
        run_args = [*run_args, "--no-refine-poses"]
    start = time.perf_counter()
    run = subprocess.run(_cli("run", str(dataset), "--mass-kg", f"{OBJECTS[name].mass_kg:g}", "--out", str(asset),
                              *run_args), capture_output=True, text=True)
    wall_s = time.perf_counter() - start
    # run prints each WARNING while running and again in its summary, worded alike up to their ends
    warnings = sorted({ln.strip()[:100] for ln in (run.stdout + run.stderr).splitlines()
                       if ln.strip().startswith("WARNING")})
    warned = "; ".join(w.replace("|", "/") for w in warnings) or "-"
    if run.returncode != 0:
        return [name, condition, seed, "-", "-", f"run failed (exit {run.returncode}): {_last_error(run.stderr)}",
                "-", "-", "-", "-", warned, round(wall_s)]
    rec = json.loads((asset / "truth.json").read_text())["reconstruction"]
    met = rec["chamfer_mm"] <= TARGET_CHAMFER_MM and rec["iou"] >= TARGET_IOU
    shape = shape_error(asset / ".run" / "reconstruct" / "mesh.obj", dataset)
    bound = frame_bound(dataset, noise)
    return [name, condition, seed, rec["chamfer_mm"], rec["iou"], "yes" if met else "no", *shape,
            f"{bound['median_mm']} ({bound['p90_mm']})", warned, round(wall_s)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default="bottle,can")
    parser.add_argument("--conditions", default=",".join(CONDITIONS), help=f"among {', '.join(CONDITIONS)}")
    parser.add_argument("--views", type=int, default=100)
    parser.add_argument("--seeds", default="0", help="capture seeds, comma-separated: each row is captured and run "
                                                     "once per seed (pose noise, cut-off views, jitter; default 0)")
    parser.add_argument("--pose-noise-mm", type=float, default=5.0, help="capture's RMS pose noise, mm (default 5)")
    parser.add_argument("--pose-noise-deg", type=float, default=1.0, help="capture's RMS pose noise, deg (default 1)")
    parser.add_argument("--quick", action="store_true", help="the can, all conditions together, tiny (smoke test)")
    parser.add_argument("--full", action="store_true", help="(run_all.py) the default setting")
    parser.add_argument("--note", default="", help="a line about the conditions (e.g. a machine shared with other work)")
    parser.add_argument("--keep", type=Path, default=None, help="keep the captures and assets here")
    parser.add_argument("--tag", default="", help="write benchmarks/results/hard_captures_TAG.md (a partial run beside "
                                                   "the main section)")
    parser.add_argument("--prepare", type=Path, default=None, metavar="DIR",
                        help="only capture and refine each case into DIR/<object>_<condition> (for --datasets)")
    parser.add_argument("--datasets", type=Path, default=None, metavar="DIR",
                        help="reconstruct the cases --prepare made in DIR with run's settings (a GPU machine has "
                             "no Drake or COLMAP): reconstruction only")
    parser.add_argument("--device", default="cpu", help="--datasets: the reconstruction's device")
    parser.add_argument("--all-unrefined", action="store_true",
                        help="every frame as refine-poses leaves it when COLMAP refines none (see above)")
    args = parser.parse_args()
    objects, conditions = args.objects.split(","), args.conditions.split(",")
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
    except ValueError:
        parser.error(f"--seeds: comma-separated integers, got {args.seeds!r}")
    unknown = [c for c in conditions if c not in CONDITIONS]
    if unknown:
        parser.error(f"unknown condition(s): {', '.join(unknown)}")
    views, width, height, run_args = args.views, 320, 240, []
    if args.quick:
        objects, conditions, views, width, height = ["can"], ["all"], 16, 128, 96
        run_args = ["--steps", "300", "--voxels", "64"]
    noise = (args.pose_noise_mm, args.pose_noise_deg)
    if args.prepare is not None:
        args.prepare.mkdir(parents=True, exist_ok=True)
        prepare(objects, conditions, args.prepare, views, width, height, noise)
        return 0
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_hard_captures-"))
    work.mkdir(parents=True, exist_ok=True)
    setting = (f"{views} views at {width}x{height} px (unless the condition sets its size), camera-pose noise "
               f"{args.pose_noise_mm:g} mm / {args.pose_noise_deg:g} deg RMS; `real2sim run` "
               f"{' '.join(run_args) or 'with its defaults'} (radiance field). With the long lens the cameras stand "
               "about 5x farther away, so the same angular noise moves the object's image 5x more (1 deg is about "
               "58 px at fx = 3300 px)")
    if args.quick:
        setting += ". QUICK smoke-test setting: not the issue's targets' setting"
    if args.all_unrefined:
        setting += (". Every frame marked not refined, as refine-poses leaves them when COLMAP refines none, and "
                    "`run --no-refine-poses`: the reconstruction aligns all views by their silhouettes")
    if args.datasets is not None:
        setting = (f"Reconstruction only: `reconstruct` with `run`'s settings, on {args.device}, of the cases "
                   "`--prepare` captured and refined with `refine-poses` beforehand (" + setting.split("; ")[0] + ")")
    rows, verb = [], "run" if args.datasets is None else "reconstruct"
    for name in objects:
        for condition in conditions:
            if args.datasets is not None:
                dataset = args.datasets / f"{name}_{condition}"
                if not dataset.is_dir():
                    continue
                rows.append(reconstruct_condition(name, condition, dataset, args.device))
                print(rows[-1], flush=True)
            else:
                for seed in seeds:
                    rows.append(run_condition(name, condition, work, views, width, height, run_args, noise,
                                              args.all_unrefined, seed))
                    print(rows[-1], flush=True)
            flags = "\n".join(f"- `{c}`: `capture {' '.join(_flags(c, width, height))}`" for c in conditions)
            body = ((args.note + "\n\n" if args.note else "") + setting + f". Target: Chamfer <= {TARGET_CHAMFER_MM} "
                    f"mm and IoU >= {TARGET_IOU} against the true object (truth.json).\n\n"
                    + markdown_table(["object", "condition"] + (["capture seed"] if verb == "run" else [])
                                     + ["Chamfer mm", "IoU", "target met"]
                                     + (["shape Chamfer mm", "shape IoU", "frame offset mm",
                                         "frame bound mm, median (p90)"] if verb == "run" else [])
                                     + [f"{verb} WARNING lines", f"{verb} wall s"], rows)
                    + "\n\nConditions:\n\n" + flags
                    + ("\n\nShape: the reconstruction's mesh moved by the translation that best lays it on the true "
                       "object (frame offset: that translation's length); the world frame is as sure as the given "
                       "poses' mean when every pose is off. Frame bound: how far the given poses alone place the "
                       "object, over 200 draws of the capture's pose noise on its true poses (the views' common "
                       "point, `silhouette_poses.common_point`, from the true masks)." if verb == "run" else ""))
            section, title = "hard_captures", ("Hard captures: `run` on turntable, long-lens, cut-off, no-table, "
                                               "jittered and JPEG captures")
            if args.datasets is not None:
                section, title = "hard_captures_reconstruct", f"Hard captures: the reconstruction alone, on {args.device}"
            if args.all_unrefined:
                section, title = "hard_captures_unrefined", "Hard captures whose poses COLMAP cannot refine"
            if args.tag:
                section, title = f"{section}_{args.tag}", f"{title} ({args.tag})"
            print(write_result(section, title, body,
                                "python benchmarks/bench_hard_captures.py " + " ".join(sys.argv[1:])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
