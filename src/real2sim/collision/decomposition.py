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
CoACD's raw hulls of a dense mesh can have thousands of vertices, and as compliant
hydroelastic convex shapes they are slow and sometimes make Drake fail ("Cannot
instantiate plane from normal"). CoACD's decimation keeps a subset of the hull's
vertices, so the hull shrinks; 128 vertices is fast without the visible shrink of 64
(docs/design-notes/collision.md#coacd-hull-decimation). The paper gives only the threshold
(0.05); pass ``CoacdConfig(decimate=False)`` for raw hulls, or ``max_ch_vertex=64`` for a
faster, coarser setting.
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
    """Options of ``coacd.run_coacd`` (names as in CoACD); the paper's threshold, the library's
    defaults otherwise except hull decimation."""

    threshold: float = 0.05
    """Concavity threshold (of the normalised mesh), in (0, 1); 0.05 as in the paper."""
    max_convex_hull: int = -1
    """Upper bound on pieces after merging; -1: no bound."""
    preprocess_mode: str = "auto"
    """Remeshing of the input: "auto" (only non-manifold input), "on" (always) or "off" (never)."""
    preprocess_resolution: int = 50
    """Voxel resolution of that remeshing, >= 1."""
    resolution: int = 2000
    """Surface samples per piece used to measure concavity, >= 1."""
    mcts_nodes: int = 20
    """Child nodes per step of the cutting-plane tree search, >= 1."""
    mcts_iterations: int = 150
    """Iterations of the cutting-plane tree search, >= 1."""
    mcts_max_depth: int = 3
    """Depth of the cutting-plane tree search, >= 1."""
    merge: bool = True
    """Merge adjacent pieces while the concavity stays under the threshold."""
    decimate: bool = True
    """Reduce each hull to at most ``max_ch_vertex`` vertices (on, unlike the library's default).
    (why: docs/design-notes/collision.md#coacd-hull-decimation)"""
    max_ch_vertex: int = 128
    """Vertex budget of each hull when decimating, >= 4.
    (why: docs/design-notes/collision.md#coacd-hull-decimation)"""
    seed: int = 0
    """CoACD's random seed (``decompose(seed=...)`` overrides it when given)."""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.threshold) and 0.0 < self.threshold < 1.0):
            raise ValueError(f"CoACD threshold must be in (0, 1), got {self.threshold}")
        if self.preprocess_mode not in ("auto", "on", "off"):
            raise ValueError("CoACD preprocess_mode must be 'auto', 'on' or 'off'")
        if self.max_ch_vertex < 4:
            raise ValueError("CoACD max_ch_vertex must be at least 4")


@dataclass(frozen=True)
class VhacdConfig:
    """Options of V-HACD 4 (``vhacdx.compute_vhacd``), the library's defaults."""

    max_convex_hulls: int = 64
    """Number of pieces V-HACD aims for (4.x tends to return exactly this many), >= 1."""
    resolution: int = 400_000
    """Voxels in the voxelisation of the whole mesh, >= 1."""
    min_volume_percent_error: float = 1.0
    """Stop splitting a piece when its hull's volume error is below this, in percent, >= 0."""
    max_recursion_depth: int = 10
    """Splitting depth at most, >= 1."""
    shrink_wrap: bool = True
    """Snap hull vertices back onto the source mesh's surface."""
    fill_mode: str = "flood"
    """Interior fill of the voxelisation: "flood", "surface" or "raycast"."""
    max_vertices_per_hull: int = 64
    """Vertex budget of each hull, >= 4."""
    min_edge_length: int = 2
    """Smallest voxel edge a piece may be split down to, in voxels, >= 1."""
    find_best_plane: bool = False
    """Search for the best splitting plane (slower)."""

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
