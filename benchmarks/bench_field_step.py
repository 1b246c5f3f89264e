"""Benchmark: where one training step of the radiance field spends its time.

Reconstructs a dataset (captured and refined earlier, as ``bench_reconstruct.py --datasets``
does) and, through the reconstruction's own progress calls, times every training step and
profiles a few of them with torch.profiler: some steps on the coarse grid and some on the
fine grid, well after each stage's start. Writes, per stage, the milliseconds a step takes,
the operators that took the most host time and the most device time, how many operators a
step launches, and how often a step waits for the device (copies to the host and
synchronisations): on a GPU a step of 4096 rays is short enough that the host's work per
operator and these waits, not the arithmetic, decide its time.

    python benchmarks/bench_field_step.py --datasets DIR --objects mug --device cuda --tag cuda
    python benchmarks/bench_field_step.py          # captures and refines the mug first (100 views, 320x240)

Writes benchmarks/results/field_step[_TAG].md via benchmarks/common.py.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from common import dataclass_settings, markdown_table, write_result  # noqa: E402

# runtime calls that make the host wait for the device
_WAITS = ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaMemcpyAsync", "cudaMemcpy", "cudaEventSynchronize")


class _StepClock:
    """A progress function that times each training step and profiles ``window`` steps of each stage,
    starting ``start_fraction`` of the way through it."""

    def __init__(self, device: str, window: int, start_fraction: float, stage_steps: dict[int, int]):
        import torch

        self.torch = torch
        self.device = device
        self.window = window
        self.start_fraction = start_fraction
        self.step_times: dict[str, list[float]] = {}  # stage label -> step end times (s)
        self.profiles: dict[str, object] = {}
        self._profiler = None
        self._profiling = None
        self._steps_by_grid = stage_steps  # longest grid side (voxels) -> that stage's steps

    def _sync(self):
        if self.device.startswith("cuda"):
            self.torch.cuda.synchronize()

    def __call__(self, label: str, done: int, total: int) -> None:
        if not label.startswith("training field"):
            return
        now = time.perf_counter()
        steps = self.step_times.setdefault(label, [])
        steps.append(now)
        if self._profiling == label and len(steps) - self._profile_start >= self.window:
            self._sync()
            self._profiler.stop()
            self.profiles[label] = (self._profiler, self.window)
            self._profiler, self._profiling = None, None
            return
        stage_total = self._stage_length(label)
        if (self.window > 0 and self._profiling is None and label not in self.profiles and stage_total
                and len(steps) == max(int(self.start_fraction * stage_total), 1)):
            self._sync()
            activities = [self.torch.profiler.ProfilerActivity.CPU]
            if self.device.startswith("cuda"):
                activities.append(self.torch.profiler.ProfilerActivity.CUDA)
            self._profiler = self.torch.profiler.profile(activities=activities, with_stack=True)
            self._profiler.start()
            self._profiling, self._profile_start = label, len(steps)

    def _stage_length(self, label: str) -> int:
        # the label names the grid's shape, "training field (AxBxC)"; its longest side names the stage
        shape = [int(v) for v in label[label.index("(") + 1:label.index(")")].split("x")]
        return self._steps_by_grid.get(max(shape), 0)


def _per_step_ms(times: list[float]) -> float:
    gaps = [b - a for a, b in zip(times, times[1:])]
    gaps.sort()
    return 1000.0 * gaps[len(gaps) // 2] if gaps else float("nan")


def _profile_rows(profile, steps: int, device: str, top: int) -> tuple[list, list, dict]:
    events = profile.key_averages()
    cuda = device.startswith("cuda")

    def device_us(e) -> float:
        return float(getattr(e, "self_device_time_total", getattr(e, "self_cuda_time_total", 0.0)) or 0.0)

    ops = [e for e in events if e.key.startswith("aten::")]
    by_host = sorted(ops, key=lambda e: -e.self_cpu_time_total)[:top]
    host_rows = [[e.key, e.count / steps, e.self_cpu_time_total / 1000.0 / steps] for e in by_host]
    device_rows = []
    if cuda:
        kernels = [e for e in events if device_us(e) > 0 and not e.key.startswith("aten::")]
        for e in sorted(kernels, key=lambda e: -device_us(e))[:top]:
            device_rows.append([e.key[:90], e.count / steps, device_us(e) / 1000.0 / steps])
    by_line: dict[str, list[float]] = {}
    for e in profile.events():
        if not e.name.startswith("aten::") or e.cpu_parent is not None and e.cpu_parent.name.startswith("aten::"):
            continue  # operators called by other operators are counted with their caller
        frame, parent = "(outside real2sim)", e.cpu_parent
        while parent is not None:  # with_stack: the Python frames are the operators' parents
            if "real2sim/" in parent.name:
                frame = parent.name
                break
            parent = parent.cpu_parent
        entry = by_line.setdefault(frame.split("real2sim/")[-1], [0, 0.0])
        entry[0] += 1
        entry[1] += e.cpu_time_total
    line_rows = [[k, n / steps, us / 1000.0 / steps] for k, (n, us) in
                 sorted(by_line.items(), key=lambda kv: -kv[1][1])[:top]]
    totals = {
        "top-level aten operators per step": sum(n for n, _ in by_line.values()) / steps,
        "aten operators per step": sum(e.count for e in ops) / steps,
        "host ms in aten operators per step (self)": sum(e.self_cpu_time_total for e in ops) / 1000.0 / steps,
        "waits for the device per step": sum(e.count for e in events if e.key in _WAITS) / steps,
        "host ms in those waits per step": sum(e.self_cpu_time_total for e in events if e.key in _WAITS) / 1000.0 / steps,
    }
    if cuda:
        totals["device ms in kernels per step"] = sum(device_us(e) for e in events if device_us(e) > 0
                                                      and not e.key.startswith("aten::")) / 1000.0 / steps
    return host_rows, device_rows, line_rows, totals


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", type=Path, default=None, metavar="DIR",
                    help="reconstruct DIR/<object> (captured and refined, with ground_truth/); default: capture "
                         "and refine each bundled object first, as bench_reconstruct.py does")
    ap.add_argument("--objects", default="mug")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--window", type=int, default=20, help="steps profiled per stage (0: none, the steps only timed)")
    ap.add_argument("--top", type=int, default=15, help="operators and kernels listed per stage")
    ap.add_argument("--steps", type=int, default=None,
                    help="fine-grid training steps (the coarse grid gets half); default: the reconstruction's")
    ap.add_argument("--field", action="append", metavar="FIELD=VALUE",
                    help="a FieldConfig number setting for this run (rays_per_step=8192, ...); repeatable")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tag", default="")
    args = ap.parse_args(argv)

    from dataclasses import replace

    from real2sim.reconstruct.stage import ReconstructConfig
    from real2sim.reconstruct.field.train import FieldConfig

    cfg = ReconstructConfig()
    try:
        cfg = replace(cfg, field=replace(cfg.field, **dataclass_settings(FieldConfig, args.field, "--field")))
    except ValueError as e:
        ap.error(str(e))
    if args.steps is not None:
        cfg = replace(cfg, field=cfg.field.with_budget(steps=args.steps))
    body = []
    with tempfile.TemporaryDirectory(prefix="bench-field-step-") as tmp:
        for name in args.objects.split(","):
            if args.datasets is None:
                from bench_reconstruct import _captured_and_refined

                capture_args = argparse.Namespace(views=100, width=320, height=240, seed=args.seed)
                _captured_and_refined(name, Path(tmp) / name, capture_args)
            body += _object_section(name, (Path(tmp) if args.datasets is None else args.datasets) / name,
                                    cfg, args)
            print("\n".join(body), flush=True)
    name = "field_step" + (f"_{args.tag}" if args.tag else "")
    command = "python benchmarks/bench_field_step.py " + " ".join(argv if argv is not None else sys.argv[1:])
    write_result(name, f"One training step of the radiance field ({args.device})", "\n".join(body), command)
    return 0


def _object_section(name: str, dataset: Path, cfg, args) -> list[str]:
    """The markdown of one object's reconstruction: its stages, its steps' times and their profiles."""
    from real2sim.reconstruct.stage import reconstruct

    body = []
    f = cfg.field.on_device(args.device)  # the steps as this device takes them
    clock = _StepClock(args.device, args.window, start_fraction=0.5,
                       stage_steps={f.coarse_voxels: f.coarse_steps, f.fine_voxels: f.fine_steps})
    t0 = time.perf_counter()
    result = reconstruct(dataset, cfg, device=args.device, seed=args.seed, progress=clock)
    wall = time.perf_counter() - t0
    r = result.report
    truth = r.get("truth", {})
    stage_rows = []
    for label, times in clock.step_times.items():
        stage_rows.append([label, len(times), _per_step_ms(times), times[-1] - times[0]])
    body.append(f"### {name}\n\nWhole reconstruction {wall:.1f} s (Chamfer {truth.get('chamfer_mm', '-')} mm); "
                "stages: " + ", ".join(f"{k} {v['seconds']:.3g}" for k, v in r["stages"].items()) + " s; "
                "train_field's phases: "
                + ", ".join(f"{k} {v:.3g}" for k, v in r.get("train_field_phase_seconds", {}).items()) + " s.\n")
    body.append(markdown_table(["stage", "steps", "median ms per step", "stage s"], stage_rows))
    for label, (profile, steps) in clock.profiles.items():
        host_rows, device_rows, line_rows, totals = _profile_rows(profile, steps, args.device, args.top)
        body.append(f"\n#### {label}: {steps} steps profiled\n")
        body.append(markdown_table(["per step", "value"], [[k, v] for k, v in totals.items()]))
        if any(row[0] != "(outside real2sim)" for row in line_rows):  # the Python frames were recorded
            body.append("\nTop-level operators by the line of real2sim that called them (host time with callees):\n")
            body.append(markdown_table(["line", "operators per step", "host ms per step"], line_rows))
        body.append("\nOperators by host time (self):\n")
        body.append(markdown_table(["operator", "calls per step", "host ms per step"], host_rows))
        if device_rows:
            body.append("\nKernels by device time:\n")
            body.append(markdown_table(["kernel", "launches per step", "device ms per step"], device_rows))
    return body


if __name__ == "__main__":
    raise SystemExit(main())
