"""Benchmark: `real2sim asset` on meshes with the defects of real scans, judged against the true solid.

A capsule (8 cm long, 3 cm radius) is the true object. Each case is a mesh of it as a scan might
deliver it:

  closed       the capsule as it is (the control)
  open top     the triangles of its top cap missing (the scanner never saw it)
  debris       three 2 mm specks 6-10 cm away from it (reconstruction debris)
  dense noisy  280k faces with 0.2 mm noise on every vertex and two open seams

Each goes through `build_asset` with cylinders:4, coacd and vhacd. Reported per representation:
pieces, IoU and Chamfer distance against the **true closed capsule** (not the scan), in the asset
frame, and the seconds of the fit; and whether CoACD / V-HACD got the mesh remeshed closed.

    python benchmarks/bench_scans.py
Writes benchmarks/results/scans.md (machine, date, command) via benchmarks/common.py.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import markdown_table, write_result  # noqa: E402

SPECS = ("cylinders:4", "coacd", "vhacd")


def _cases(seed: int) -> dict:
    import trimesh

    truth = trimesh.creation.capsule(height=0.08, radius=0.03, count=[48, 48])
    rng = np.random.default_rng(seed)
    open_top = truth.copy()
    open_top.update_faces(open_top.triangles_center[:, 2] < 0.055)
    open_top.remove_unreferenced_vertices()
    specks = []
    for at in ((0.1, 0.0, 0.0), (0.0, 0.09, 0.03), (-0.06, -0.05, -0.04)):
        speck = trimesh.creation.icosphere(2, 0.002)
        speck.apply_translation(at)
        specks.append(speck)
    debris = trimesh.util.concatenate([truth, *specks])
    dense = trimesh.creation.capsule(height=0.08, radius=0.03, count=[400, 400])
    dense = trimesh.Trimesh(dense.vertices + rng.normal(0, 0.0002, dense.vertices.shape), dense.faces, process=False)
    return truth, {"closed": truth, "open top": open_top, "debris": debris, "dense noisy": dense}


def measure(name: str, mesh, truth, work: Path, seed: int) -> list[list]:
    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.formats.collision import read_collision_json
    from real2sim.formats.spec import parse_spec
    from real2sim.geometry.fidelity import measure_fidelity

    path = work / f"{name.replace(' ', '_')}.ply"
    mesh.export(path)
    out = work / f"{name.replace(' ', '_')}_asset"
    result = build_asset(path, out, AssetConfig(mass_kg=0.3, specs=tuple(parse_spec(s) for s in SPECS), seed=seed))
    true_in_asset = truth.copy()
    true_in_asset.apply_transform(result.canonical_transform)
    rows = []
    for rep in result.representations:
        rep_dir = out / rep.name
        fidelity = measure_fidelity(true_in_asset, read_collision_json(rep_dir / "collision.json"), rep_dir, seed=seed)
        rows.append([name, len(mesh.faces), rep.fit_report["spec"], fidelity["num_pieces"], round(fidelity["iou"], 3),
                     round(fidelity["chamfer_mm"], 2), round(rep.fit_report["fit_seconds"], 1),
                     rep.fit_report.get("input_closed_by", "-")])
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    truth, cases = _cases(args.seed)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-scans-") as tmp:
        for name, mesh in cases.items():
            rows += measure(name, mesh, truth, Path(tmp), args.seed)
    body = (
        "`build_asset` (cylinders:4, coacd, vhacd; 0.3 kg) on a capsule (8 cm long, 3 cm radius) delivered as "
        "a scan might be. IoU and Chamfer are against the true closed capsule, in the asset frame; `closed by`: "
        "what CoACD / V-HACD were given (`remesh`: the solid the open mesh bounds, remeshed closed).\n\n"
        + markdown_table(["case", "faces", "SPEC", "pieces", "IoU vs truth", "Chamfer mm", "fit s", "closed by"], rows)
        + "\n"
    )
    command = "python benchmarks/bench_scans.py " + " ".join(argv if argv is not None else sys.argv[1:])
    print(write_result("scans", "Meshes with the defects of real scans (benchmarks/bench_scans.py)", body,
                        command.strip()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
