"""What an asset folder's geometry tells identification (``identify --shape ASSETDIR``), in the
object's own mesh frame: a bounding ellipsoid for the mass and the uniform-density parameters."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from real2sim.plumbing.errors import UserInputError
from real2sim.formats.physical import parse_properties
from real2sim.identify.arm import phi_from_properties
from real2sim.identify.solve import ShapePrior


def bounding_ellipsoid(points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre, E) of an ellipsoid ``(x - c)^T E (x - c) <= 1`` holding every point: the one through
    the corners of the points' box along their principal axes (semi-axes sqrt(3) half-sides)."""
    pts = np.asarray(points_m, dtype=float)
    mean = pts.mean(axis=0)
    _, _, axes = np.linalg.svd(pts - mean, full_matrices=False)
    local = (pts - mean) @ axes.T
    lo, hi = local.min(axis=0), local.max(axis=0)
    centre = mean + axes.T @ (0.5 * (lo + hi))
    semi = np.sqrt(3.0) * np.maximum(0.5 * (hi - lo), 1e-4)
    return centre, axes.T @ np.diag(1.0 / semi ** 2) @ axes


def shape_prior_from_asset(asset_dir: Path) -> ShapePrior:
    """The prior of ``asset_dir`` (made by `real2sim asset` from the same mesh the grasp refers to)."""
    import trimesh

    asset_dir = Path(asset_dir)
    try:
        transform = np.asarray(json.loads((asset_dir / "canonical_transform.json").read_text())["T_asset_from_input"])
        props, _ = parse_properties(asset_dir / "physical_properties.json", "--shape ")
        solid = trimesh.load(asset_dir / "visual" / "collision_reference.obj", force="mesh", process=False)
    except (OSError, ValueError, KeyError) as exc:
        raise UserInputError(f"--shape {asset_dir} is not an asset folder of real2sim asset ({exc})") from None
    # back into the input mesh's frame
    solid.apply_transform(np.linalg.inv(transform))
    if not (solid.is_watertight and float(solid.volume) > 0):
        raise UserInputError(f"--shape {asset_dir}: its collision_reference.obj is not a closed solid")
    return shape_prior_from_mesh(solid, props.mass_kg)


def shape_prior_from_mesh(solid, mass_kg: float) -> ShapePrior:
    """The prior of a closed mesh (metres, its own frame) of ``mass_kg``."""
    mass = float(mass_kg)
    inertia = np.asarray(solid.moment_inertia) * (mass / float(solid.volume))
    centre, matrix = bounding_ellipsoid(solid.vertices)
    return ShapePrior(ellipsoid_centre_m=centre, ellipsoid_matrix=matrix,
                      uniform_phi=phi_from_properties(mass, np.asarray(solid.center_mass), inertia),
                      size_m=float(np.max(solid.extents)))
