"""Convex-decomposition baselines and the mesh-as-is baseline (paper V-C's CoACD row).

:func:`decompose` turns a mesh in the asset (canonical) frame into a
:class:`~real2sim.formats.collision.CollisionGeometry` and writes its pieces under
``rep_dir/pieces/``:

* ``coacd``: CoACD (Wei et al. 2022), approximate convex decomposition driven by
  a concavity threshold. The paper compares against CoACD with threshold 0.05;
  every other option keeps the library's default except hull decimation (below).
* ``vhacd``: V-HACD 4 (voxel-based), through ``vhacdx``; library defaults except
  a synchronous run.
* ``mesh``: the mesh itself, one non-convex ``mesh`` shape (``pieces/mesh.obj``).

Convex pieces are written as ``pieces/piece_NNN.obj`` with vertices in the asset
frame and the identity pose, each the exact convex hull (qhull) of the library's
output, so that Drake's ``<drake:declare_convex/>`` sees the same solid. Pieces
that are degenerate (flat, or less than a millionth of the total volume) are
dropped: they carry no volume and Drake cannot build a hydroelastic mesh for them.

Hull decimation (``CoacdConfig.decimate``, default on, at most 128 vertices per hull):
CoACD's raw hulls of a dense mesh can have thousands of vertices (1924 for the main
hull of our 5.9k-face bottle); as compliant hydroelastic convex shapes they are slow
(that bottle rolling on a compliant floor: ~15 wall s per simulated s) and sometimes
make Drake fail ("Cannot instantiate plane from normal"). CoACD's decimation keeps a
subset of the hull's vertices, so the hull shrinks: on the bottle the pieces kept
87.2% of the volume at 64 vertices, 94.4% at 128 and 97.2% at 256, and simulated at
about 0.5-0.8, 0.6-1.4 and ~5 wall s per simulated s (2 loaded cores, noisy). 128 is
the default: it is >10x faster than raw hulls without the ~2 mm radial shrink that
64 vertices cause, which would handicap the baseline's accuracy. The paper gives
only the threshold (0.05); pass ``CoacdConfig(decimate=False)`` for raw hulls, or
``max_ch_vertex=64`` for the faster, coarser setting of DESIGN.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from real2sim.formats.collision import CollisionGeometry, CollisionShape

METHODS = ("coacd", "vhacd", "mesh")
PIECES_DIR = "pieces"
_MIN_RELATIVE_VOLUME = 1e-6  # pieces below this fraction of the total are slivers


@dataclass(frozen=True)
class CoacdConfig:
    """Options of ``coacd.run_coacd`` (names as in CoACD).

    threshold: concavity threshold (of the normalised mesh); 0.05 as in the paper.
    max_convex_hull: upper bound on pieces after merging; -1 = no bound.
    preprocess_mode: "auto" remeshes only non-manifold input, "on" always, "off" never.
    preprocess_resolution: voxel resolution of that remeshing.
    resolution: surface samples per piece used to measure concavity.
    mcts_nodes, mcts_iterations, mcts_max_depth: the cutting-plane tree search.
    merge: merge adjacent pieces while the concavity stays under the threshold.
    decimate, max_ch_vertex: reduce each hull to at most max_ch_vertex vertices
        (default on, 128: see the module docstring for why).
    seed: CoACD's random seed (overridden by ``decompose(seed=...)`` when given).
    """

    threshold: float = 0.05
    max_convex_hull: int = -1
    preprocess_mode: str = "auto"
    preprocess_resolution: int = 50
    resolution: int = 2000
    mcts_nodes: int = 20
    mcts_iterations: int = 150
    mcts_max_depth: int = 3
    merge: bool = True
    decimate: bool = True
    max_ch_vertex: int = 128
    seed: int = 0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.threshold) and 0.0 < self.threshold < 1.0):
            raise ValueError(f"CoACD threshold must be in (0, 1), got {self.threshold}")
        if self.preprocess_mode not in ("auto", "on", "off"):
            raise ValueError("CoACD preprocess_mode must be 'auto', 'on' or 'off'")
        if self.max_ch_vertex < 4:
            raise ValueError("CoACD max_ch_vertex must be at least 4")


@dataclass(frozen=True)
class VhacdConfig:
    """Options of V-HACD 4 (``vhacdx.compute_vhacd``), library defaults.

    max_convex_hulls: number of pieces V-HACD aims for (4.x tends to return exactly this many).
    resolution: voxels in the voxelisation of the whole mesh.
    min_volume_percent_error: stop splitting a piece when its hull volume error is below this (%).
    max_recursion_depth: splitting depth.
    shrink_wrap: snap hull vertices back onto the source mesh surface.
    fill_mode: interior fill of the voxelisation, "flood", "surface" or "raycast".
    max_vertices_per_hull: vertex budget of each hull.
    min_edge_length: smallest voxel edge a piece may be split down to, in voxels.
    find_best_plane: search for the best splitting plane (slower).
    """

    max_convex_hulls: int = 64
    resolution: int = 400_000
    min_volume_percent_error: float = 1.0
    max_recursion_depth: int = 10
    shrink_wrap: bool = True
    fill_mode: str = "flood"
    max_vertices_per_hull: int = 64
    min_edge_length: int = 2
    find_best_plane: bool = False

    def __post_init__(self) -> None:
        if self.fill_mode not in ("flood", "surface", "raycast"):
            raise ValueError("V-HACD fill_mode must be 'flood', 'surface' or 'raycast'")
        if self.max_convex_hulls < 1:
            raise ValueError("V-HACD max_convex_hulls must be at least 1")


def _run_coacd(mesh: trimesh.Trimesh, config: CoacdConfig, seed: int) -> list[np.ndarray]:
    import coacd

    coacd.set_log_level("error")  # CoACD logs every cut at info level
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)),
        threshold=config.threshold,
        max_convex_hull=config.max_convex_hull,
        preprocess_mode=config.preprocess_mode,
        preprocess_resolution=config.preprocess_resolution,
        resolution=config.resolution,
        mcts_nodes=config.mcts_nodes,
        mcts_iterations=config.mcts_iterations,
        mcts_max_depth=config.mcts_max_depth,
        merge=config.merge,
        decimate=config.decimate,
        max_ch_vertex=config.max_ch_vertex,
        seed=int(seed),
    )
    return [np.asarray(v, dtype=np.float64) for v, _ in parts]


def vhacd_point_sets(mesh: trimesh.Trimesh, config: VhacdConfig) -> list[np.ndarray]:
    """Vertices (k_i, 3) of each V-HACD convex piece of ``mesh``, in the mesh's frame."""
    from vhacdx import compute_vhacd

    # vhacdx takes faces flattened VTK-style, each triangle prefixed by its vertex count
    # (a plain (F, 3) array is accepted silently and yields hulls of garbage surface slivers).
    faces = np.column_stack((np.full(len(mesh.faces), 3), mesh.faces)).ravel().astype(np.uint32)
    hulls = compute_vhacd(
        np.asarray(mesh.vertices, dtype=np.float64),
        faces,
        maxConvexHulls=config.max_convex_hulls,
        resolution=config.resolution,
        minimumVolumePercentErrorAllowed=config.min_volume_percent_error,
        maxRecursionDepth=config.max_recursion_depth,
        shrinkWrap=config.shrink_wrap,
        fillMode=config.fill_mode,
        maxNumVerticesPerCH=config.max_vertices_per_hull,
        asyncACD=False,
        minEdgeLength=config.min_edge_length,
        findBestPlane=config.find_best_plane,
    )
    return [np.asarray(v, dtype=np.float64) for v, _ in hulls]


def _hulls(point_sets: list[np.ndarray]) -> list[trimesh.Trimesh]:
    """Exact convex hulls of the pieces' vertices, slivers dropped."""
    hulls = []
    for pts in point_sets:
        if len(pts) < 4:
            continue
        try:
            hull = trimesh.convex.convex_hull(pts)  # qhull; raises on flat input
        except Exception:
            continue
        if hull.volume > 0:
            hulls.append(hull)
    if not hulls:
        return hulls
    total = sum(h.volume for h in hulls)
    return [h for h in hulls if h.volume >= _MIN_RELATIVE_VOLUME * total]


def decompose(
    mesh_canonical: trimesh.Trimesh,
    method: str,
    rep_dir: Path,
    *,
    coacd_config: CoacdConfig = CoacdConfig(),
    vhacd_config: VhacdConfig = VhacdConfig(),
    seed: int | None = None,
) -> CollisionGeometry:
    """Decompose ``mesh_canonical`` (asset frame, metres) and write its pieces under ``rep_dir``.

    method: "coacd" or "vhacd" (shapes of kind "convex", ``pieces/piece_NNN.obj``) or
        "mesh" (one shape of kind "mesh", ``pieces/mesh.obj``, the input as it is).
    seed: CoACD's seed; None keeps ``coacd_config.seed``. V-HACD is deterministic.
    Returns the geometry (name and spec = method) with mesh paths relative to ``rep_dir``.
    Raises ValueError for an unknown method and RuntimeError when a decomposition
    produces no usable piece.
    """
    if method not in METHODS:
        raise ValueError(f"unknown decomposition method {method!r}; choose one of {METHODS}")
    pieces_dir = Path(rep_dir) / PIECES_DIR
    pieces_dir.mkdir(parents=True, exist_ok=True)
    for stale in pieces_dir.glob("piece_*.obj"):
        stale.unlink()  # a rerun with fewer pieces must not leave old ones behind

    if method == "mesh":
        plain = trimesh.Trimesh(np.asarray(mesh_canonical.vertices), np.asarray(mesh_canonical.faces), process=False)
        rel = f"{PIECES_DIR}/mesh.obj"
        plain.export(Path(rep_dir) / rel, include_normals=False, include_texture=False)
        return CollisionGeometry(name="mesh", spec="mesh", shapes=(CollisionShape(kind="mesh", mesh_file=rel),))

    if method == "coacd":
        point_sets = _run_coacd(mesh_canonical, coacd_config, coacd_config.seed if seed is None else seed)
    else:
        point_sets = vhacd_point_sets(mesh_canonical, vhacd_config)
    hulls = _hulls(point_sets)
    if not hulls:
        raise RuntimeError(f"{method} produced no convex piece with volume for this mesh")

    shapes = []
    for k, hull in enumerate(hulls):
        rel = f"{PIECES_DIR}/piece_{k:03d}.obj"
        hull.export(Path(rep_dir) / rel, include_normals=False)
        shapes.append(CollisionShape(kind="convex", mesh_file=rel))
    return CollisionGeometry(name=method, spec=method, shapes=tuple(shapes))
