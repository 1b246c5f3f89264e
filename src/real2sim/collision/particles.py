"""Voxel-particle collision geometry: the baseline the paper's appendix compares sphere fitting to.

GPU physics engines (GPU Gems 3, ch. 29) represent a rigid body by particles:
voxelise the space around the mesh and put one sphere in every voxel that is
inside the object, a yes/no decision per voxel with no optimisation. The paper's
Fig. 10 shows that fitted spheres reach the same fidelity with far fewer spheres
(256 fitted vs about ten thousand particles).

Here a voxel is kept when its *centre* is inside the mesh (generalized winding
number, :func:`real2sim.geometry.inside.inside_mask`, robust to holes and internal faces).
The grid is centred on the mesh's axis-aligned bounding box. Every particle is a
sphere of radius ``radius_fraction * voxel_size_m``: 0.5 (default) gives touching
particles as in GPU Gems, which fill pi/6 (52%) of each voxel's volume; sqrt(3)/2
makes each sphere cover its whole voxel, bulging out of the surface by up to
0.37 voxel. All in the mesh's (asset) frame, metres.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.plumbing.errors import UserInputError

MAX_VOXELS = 20_000_000  # grid cells tested for one representation (memory ~ 0.5 GB of float64 centres)
TOUCHING = 0.5
COVERING = math.sqrt(3.0) / 2.0


def voxel_centres_inside(mesh: trimesh.Trimesh, voxel_size_m: float) -> np.ndarray:
    """Centres (K, 3), metres, of the voxels of a bounding-box-centred grid whose centre is inside ``mesh``."""
    from real2sim.geometry.inside import inside_mask

    if not np.isfinite(voxel_size_m) or voxel_size_m <= 0:
        raise UserInputError(f"voxel size must be a positive length in metres, got {voxel_size_m}")
    lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
    counts = np.maximum(np.ceil((hi - lo) / voxel_size_m).astype(np.int64), 1)
    total = int(np.prod(counts))
    if total > MAX_VOXELS:
        raise UserInputError(
            f"voxel size {voxel_size_m:g} m is too fine for this mesh: {total} voxels (limit {MAX_VOXELS})"
        )
    # Centre the grid on the bounding box so the result does not depend on where the mesh sits.
    start = 0.5 * (lo + hi) - 0.5 * voxel_size_m * (counts - 1)
    axes = [start[k] + voxel_size_m * np.arange(counts[k]) for k in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return centres[inside_mask(mesh, centres)]


def particle_spheres(
    mesh: trimesh.Trimesh,
    voxel_size_m: float,
    *,
    radius_fraction: float = TOUCHING,
    spec: str | None = None,
) -> CollisionGeometry:
    """One sphere (radius ``radius_fraction * voxel_size_m``) per voxel whose centre is inside ``mesh``.

    The geometry's spec is ``spec`` or ``"particles:<count>"``; its name is the
    spec with ``:`` turned into ``_``. Raises UserInputError when no voxel centre
    is inside (voxel too coarse, or a mesh that encloses no volume).
    """
    if not radius_fraction > 0:
        raise ValueError(f"radius_fraction must be positive, got {radius_fraction}")
    centres = voxel_centres_inside(mesh, voxel_size_m)
    if len(centres) == 0:
        raise UserInputError(
            f"no voxel centre lies inside the mesh at voxel size {voxel_size_m:g} m; use a finer voxel or a closed mesh"
        )
    radius = float(radius_fraction * voxel_size_m)
    shapes = tuple(CollisionShape("sphere", (radius,), tuple(float(x) for x in c)) for c in centres)
    spec = spec or f"particles:{len(shapes)}"
    return CollisionGeometry(name=spec.replace(":", "_").replace("+", "_"), spec=spec, shapes=shapes)


def voxel_size_for_count(mesh: trimesh.Trimesh, target_count: int, *, max_iterations: int = 8) -> tuple[float, int]:
    """(voxel_size_m, count): the voxel size whose inside-voxel count is closest to ``target_count``.

    Starts from ``(volume / target)^(1/3)`` and corrects by the cube root of the
    count ratio; the count is a step function of the size, so the result is the
    closest seen, not necessarily equal.
    """
    if target_count < 1:
        raise UserInputError(f"particle count must be >= 1, got {target_count}")
    from real2sim.geometry.inside import inside_mask

    lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
    box_volume = float(np.prod(hi - lo))
    # Volume estimate by the winding number on a small random set: works for open meshes too.
    rng = np.random.default_rng(0)
    fraction = float(inside_mask(mesh, lo + (hi - lo) * rng.random((4096, 3))).mean())
    volume = max(fraction, 1.0 / 4096) * box_volume
    voxel = (volume / target_count) ** (1.0 / 3.0)
    best: tuple[float, int] | None = None
    for _ in range(max_iterations):
        count = len(voxel_centres_inside(mesh, voxel))
        if best is None or abs(math.log(max(count, 1) / target_count)) < abs(math.log(max(best[1], 1) / target_count)):
            best = (voxel, count)
        if count == target_count:
            break
        # count ~ volume / voxel^3
        voxel *= (max(count, 0.5) / target_count) ** (1.0 / 3.0)
    assert best is not None
    return best


def particles_for_count(
    mesh: trimesh.Trimesh, target_count: int, *, radius_fraction: float = TOUCHING
) -> CollisionGeometry:
    """Particle spheres with about ``target_count`` particles; spec ``"particles:<target_count>"``."""
    voxel, _ = voxel_size_for_count(mesh, target_count)
    return particle_spheres(mesh, voxel, radius_fraction=radius_fraction, spec=f"particles:{target_count}")
