"""Dynamics judged against the true object: what the paper could not measure.

The paper's protocol simulates every representation against the reconstruction (its
closed mesh, with the asset's estimated mass properties). A simulated capture knows
the true object, so the same sweep is also run against a reference made of the
**true mesh with the true mass properties** (same mass, inertia and CoM computed from
the true mesh by the asset stage's own function, in the asset frame):

* ``ASSETDIR/results``        representations vs the reconstruction (the paper's protocol);
* ``ASSETDIR/results_truth``  representations vs the true object; the ``mesh``
  representation (the reconstruction itself, added to the asset for this) gives the
  reconstruction's own error against the truth.

:func:`dynamics_record` joins both summaries for ``truth.json``: per representation and
contact model, OCAE and ATE against the truth beside OCAE against the reconstruction.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from real2sim.formats.physical import read_physical_properties, write_physical_properties

TRUE_MESH_NAME = "true_mesh_world.obj"
TRUE_PROPERTIES_NAME = "true_physical_properties.json"
RECONSTRUCTION_REPRESENTATION = "mesh"


def write_true_reference(dataset: Path, asset_dir: Path, out_dir: Path, seed: int) -> tuple[Path, Path]:
    """Write the true object as the evaluation's reference: ``out_dir/true_mesh_world.obj`` (the frame
    the asset was built from, which ``evaluate --reference`` moves by canonical_transform.json) and
    ``out_dir/true_physical_properties.json`` (asset frame, the asset's mass). Returns both paths."""
    from real2sim.asset.inertia import estimate_physical_properties
    from real2sim.pipeline.truth import true_mesh_in_asset_frame

    asset_dir, out_dir = Path(asset_dir), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    true_mesh, _ = true_mesh_in_asset_frame(dataset, asset_dir)
    mass_kg = read_physical_properties(asset_dir / "physical_properties.json").mass_kg
    props = estimate_physical_properties(true_mesh, mass_kg, seed=seed)
    props_path = out_dir / TRUE_PROPERTIES_NAME
    write_physical_properties(props, props_path)
    import json

    transform = np.asarray(json.loads((asset_dir / "canonical_transform.json").read_text())["T_asset_from_input"],
                           dtype=float)
    world = true_mesh.copy()
    world.apply_transform(np.linalg.inv(transform))  # back to the frame the asset was built from
    mesh_path = out_dir / TRUE_MESH_NAME
    world.export(mesh_path)
    return mesh_path, props_path


def _summary(path: Path) -> dict[tuple[str, str], dict]:
    with open(path, newline="") as fh:
        return {(row["collision"], row["contact_model"]): row for row in csv.DictReader(fh)}


def _number(value) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def dynamics_record(results_dir: Path, results_truth_dir: Path) -> dict:
    """The ``dynamics`` section of truth.json from the two sweeps' summary.csv files (metres)."""
    paper = _summary(Path(results_dir) / "summary.csv")
    truth = _summary(Path(results_truth_dir) / "summary.csv")
    rows = []
    for key in sorted(set(paper) | set(truth)):
        ours, real = paper.get(key, {}), truth.get(key, {})
        vs_recon, vs_truth = _number(ours.get("ocae_m")), _number(real.get("ocae_m"))
        rows.append({
            "representation": key[0], "contact_model": key[1],
            "ocae_vs_reconstruction_m": vs_recon, "ate_vs_reconstruction_m": _number(ours.get("ate_m")),
            "ocae_vs_truth_m": vs_truth, "ate_vs_truth_m": _number(real.get("ate_m")),
            "truth_over_reconstruction": (vs_truth / vs_recon) if vs_truth is not None and vs_recon else None,
        })
    reconstruction = [r for r in rows if r["representation"] == RECONSTRUCTION_REPRESENTATION]
    primitives = [r for r in rows if r["representation"] not in (RECONSTRUCTION_REPRESENTATION, "coacd", "vhacd")
                  and r["ocae_vs_reconstruction_m"] is not None and r["ocae_vs_truth_m"] is not None]
    best = min(primitives, key=lambda r: r["ocae_vs_reconstruction_m"], default=None)
    return {
        "protocol": "each representation simulated against two references in the same sweep settings: the "
                    "reconstruction (the paper's protocol, ASSETDIR/results) and the true mesh with its true mass "
                    "properties (ASSETDIR/results_truth)",
        "representations": rows,
        "reconstruction_vs_truth": reconstruction,
        "best_primitive_by_paper_protocol": best,
    }
