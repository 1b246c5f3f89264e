"""Signed-distance samples of a mesh in unit-sphere coordinates (paper IV-C2).

The fitter (:mod:`real2sim.collision.fit`) needs many points near the object's surface
with the signed distance of the mesh at each, negative inside. This stage

1. scales the mesh into the unit sphere: ``asset_point = centre_m + scale_m * unit_point``
   with ``centre_m`` the centre of the vertices' axis-aligned bounding box and
   ``scale_m`` the largest distance of a vertex from it, so every vertex lies in
   the closed unit ball and at least one on its boundary. (The bounding-box
   centre is cheap, deterministic and near the minimal enclosing sphere's
   (docs/design-notes/collision.md#unit-sphere); the fitter penalises
   primitive centres outside the unit sphere, eq. 11, so the ball must hold the
   whole mesh);
2. draws ``num_surface_samples`` area-uniform surface points and moves each by
   isotropic Gaussian noise, the samples split evenly over ``surface_sigmas``
   (default 0.0025 and 0.025 unit-sphere units). The small scale pins the
   surface down for the truncated loss (eq. 9); the large one gives the fitter
   gradient information a little off the surface and fills thin parts with
   inside samples. This two-scale split follows DeepSDF/DualSDF-style
   preprocessing (their exact variances differ);
3. adds ``num_uniform_samples`` points uniform in the ball of radius
   ``uniform_radius`` (1.3), as the paper does;
4. computes the signed distance of every point: the magnitude is the exact
   distance to the nearest triangle (libigl's AABB tree); the sign comes from the
   generalized winding number (see :mod:`real2sim.geometry.inside`), which is robust to
   holes and internal faces like the paper's ray stabbing [36], and unlike ray
   stabbing it does not fill cavities (a mug stays hollow).

Speed and the limits of the signs: :mod:`real2sim.collision.mesh_distance`.

Results are cached as ``.npz`` keyed by a hash of the mesh (vertex and face
bytes) and of the configuration, so fitting several representations of one mesh
samples it once. See :func:`default_cache_dir`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn, null_progress
from real2sim.collision.mesh_distance import boundary_edges, signed_distance_winding  # noqa: F401 (boundary_edges: public here)

_CACHE_FORMAT = 2  # bump when the sampling algorithm changes what it returns
AUTO_CACHE = "auto"


@dataclass(frozen=True)
class SdfSamplingConfig:
    """How many signed-distance samples, where, and how their signs are computed (lengths in
    unit-sphere units)."""

    num_surface_samples: int = 600_000
    """Near-surface samples (the paper's 600k), >= 0."""
    num_uniform_samples: int = 500
    """Samples uniform in the ball of radius ``uniform_radius`` (the paper's 500), >= 0; the two
    counts together > 0."""
    uniform_radius: float = 1.3
    """Radius of the ball of the uniform samples (the paper's 1.3, unit sphere), > 0."""
    surface_sigmas: tuple[float, ...] = (0.0025, 0.025)
    """Standard deviations of the isotropic Gaussian noise that moves surface points off the
    surface (unit sphere), each > 0; the near-surface samples split evenly over them.
    (why: docs/design-notes/collision.md#surface-sigmas)"""
    seed: int = 0
    """Seed of the sample draws."""
    sign_method: str = "fast"
    """"fast" (winding number once per face, carried to the points it is closest to, exact where
    doubtful: :mod:`real2sim.collision.mesh_distance`) or "exact" (at every point)."""
    sign_margin: float = 0.25
    """With "fast": a point whose inferred ``|w|`` lies within this of 0.5 gets the exact winding
    number; >= 0 (above 0.5 every point gets it)."""
    min_inside_fraction: float = 0.01
    """Fewest near-surface samples clearly inside (|w| > 0.75), as a fraction in [0, 1]; fewer
    raise UserInputError (the mesh encloses no volume)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "surface_sigmas", tuple(float(x) for x in self.surface_sigmas))
        if self.num_surface_samples < 0 or self.num_uniform_samples < 0:
            raise ValueError("sample counts must be >= 0")
        if self.num_surface_samples + self.num_uniform_samples == 0:
            raise ValueError("need at least one sample")
        if not self.surface_sigmas or any(not np.isfinite(s) or s <= 0 for s in self.surface_sigmas):
            raise ValueError(f"surface_sigmas must be positive, got {self.surface_sigmas}")
        if not self.uniform_radius > 0:
            raise ValueError(f"uniform_radius must be positive, got {self.uniform_radius}")
        if self.sign_method not in ("fast", "exact"):
            raise ValueError(f"sign_method must be 'fast' or 'exact', got {self.sign_method!r}")


@dataclass(frozen=True, eq=False)
class SdfSamples:
    """Signed-distance samples in unit-sphere coordinates.

    ``points`` (N, 3) float32 and ``sdf`` (N,) float32 (negative inside) are in
    unit-sphere units; the first ``num_surface`` rows are the near-surface samples,
    the rest the uniform ones. The asset frame (metres) is
    ``asset_point = centre_m + scale_m * unit_point`` and ``sdf_m = scale_m * sdf``.
    ``from_cache`` says whether the arrays were loaded rather than computed.
    """

    points: np.ndarray
    sdf: np.ndarray
    centre_m: np.ndarray  # (3,) float64
    scale_m: float
    num_surface: int
    from_cache: bool = False

    @property
    def scale(self) -> float:
        """Alias of ``scale_m``: metres per unit-sphere unit."""
        return self.scale_m

    def to_asset(self, unit_points: np.ndarray) -> np.ndarray:
        """Unit-sphere points (..., 3) -> asset-frame points in metres (float64)."""
        return self.centre_m + self.scale_m * np.asarray(unit_points, dtype=np.float64)

    def to_unit(self, points_m: np.ndarray) -> np.ndarray:
        """Asset-frame points in metres (..., 3) -> unit-sphere points (float64)."""
        return (np.asarray(points_m, dtype=np.float64) - self.centre_m) / self.scale_m

    def points_m(self) -> np.ndarray:
        """The sample points in the asset frame, metres (N, 3) float64."""
        return self.to_asset(self.points)

    def sdf_m(self) -> np.ndarray:
        """The signed distances in metres (N,) float64."""
        return self.scale_m * self.sdf.astype(np.float64)

    def inside(self) -> np.ndarray:
        """Boolean (N,): the samples inside the mesh (sdf < 0)."""
        return self.sdf < 0


def default_cache_dir() -> Path:
    """``$REAL2SIM_CACHE/sdf`` when that variable is set, else ``~/.cache/real2sim/sdf``."""
    root = os.environ.get("REAL2SIM_CACHE")
    return Path(root) / "sdf" if root else Path.home() / ".cache" / "real2sim" / "sdf"


def unit_sphere_transform(mesh: trimesh.Trimesh) -> tuple[np.ndarray, float]:
    """(centre_m, scale_m) with ``asset = centre_m + scale_m * unit`` putting all vertices in the unit ball.

    Centre: the centre of the vertices' axis-aligned bounding box. Scale: the
    largest vertex distance from it.
    """
    v = np.asarray(mesh.vertices, dtype=np.float64)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    scale = float(np.sqrt(((v - centre) ** 2).sum(axis=1).max()))
    return centre, scale


def sample_sdf(
    mesh: trimesh.Trimesh,
    config: SdfSamplingConfig = SdfSamplingConfig(),
    *,
    cache_dir: Path | str | None = AUTO_CACHE,
    progress: ProgressFn | None = None,
) -> SdfSamples:
    """Signed-distance samples of ``mesh`` (metres, asset frame) in unit-sphere coordinates.

    ``cache_dir``: folder of cached samples; ``"auto"`` (default) is
    :func:`default_cache_dir`, ``None`` disables the cache. Raises
    :class:`UserInputError` for an empty or degenerate mesh, or one that encloses
    no volume (fewer than ``min_inside_fraction`` of the near-surface samples
    clearly inside, |winding number| > 0.75).
    """
    from real2sim.geometry.mesh_io import validate_mesh

    validate_mesh(mesh, "mesh")
    v = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    f = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    centre, scale = unit_sphere_transform(mesh)
    if not np.isfinite(scale) or scale <= 0:
        raise UserInputError("mesh is degenerate: all vertices coincide")

    cache_file = None
    if cache_dir is not None:
        folder = default_cache_dir() if cache_dir == AUTO_CACHE else Path(cache_dir)
        cache_file = folder / f"{_cache_key(v, f, config)}.npz"
        cached = _load_cache(cache_file)
        if cached is not None:
            return cached

    v_unit = (v - centre) / scale
    steps = _Steps(progress)
    with steps:
        rng = np.random.default_rng(config.seed)
        near = _near_surface_points(v_unit, f, config, rng)
        uniform = _uniform_ball_points(config.num_uniform_samples, config.uniform_radius, rng)
        points = np.concatenate([near, uniform])
        steps.advance("distances and signs")
        sdf, winding = signed_distance_winding(v_unit, f, points, config.sign_method, config.sign_margin,
                                               before_signs=lambda: steps.advance("signs"))
    n_near = len(near)
    _check_encloses_volume(winding[:n_near], config.min_inside_fraction)

    samples = SdfSamples(
        points=points.astype(np.float32),
        sdf=sdf.astype(np.float32),
        centre_m=centre,
        scale_m=scale,
        num_surface=n_near,
        from_cache=False,
    )
    if cache_file is not None:
        _save_cache(cache_file, samples)
    return samples


# ---------------------------------------------------------------------------
# sampling


def _near_surface_points(v: np.ndarray, f: np.ndarray, config: SdfSamplingConfig, rng: np.random.Generator) -> np.ndarray:
    n = config.num_surface_samples
    if n == 0:
        return np.empty((0, 3))
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    cdf = np.cumsum(area)
    # Sorted uniforms make the search cache-friendly; the permutation restores iid order.
    face = np.searchsorted(cdf, np.sort(rng.random(n)) * cdf[-1], side="right").clip(0, len(f) - 1)
    face = face[rng.permutation(n)]
    # Uniform barycentric coordinates: fold the unit square onto the triangle.
    uv = rng.random((n, 2))
    flip = uv.sum(axis=1) > 1.0
    uv[flip] = 1.0 - uv[flip]
    t = tri[face]
    surface = t[:, 0] + uv[:, :1] * (t[:, 1] - t[:, 0]) + uv[:, 1:] * (t[:, 2] - t[:, 0])
    # Evenly split over the noise scales, in blocks (the points are already in random order).
    sigma = np.asarray(config.surface_sigmas, dtype=np.float64)[(np.arange(n) * len(config.surface_sigmas)) // n]
    return surface + rng.standard_normal((n, 3)) * sigma[:, None]


def _uniform_ball_points(n: int, radius: float, rng: np.random.Generator) -> np.ndarray:
    direction = rng.standard_normal((n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True).clip(1e-12)
    return direction * (radius * rng.random(n) ** (1.0 / 3.0))[:, None]


def _check_encloses_volume(near_winding: np.ndarray, min_fraction: float) -> None:
    """Refuse meshes that bound no solid.

    Counts samples *clearly* inside (|w| > 0.75): next to an open sheet the
    winding number hovers around +-0.5, so in the valleys of a wavy open sheet
    many samples pass the 0.5 test by a hair, while the inside of a closed
    surface has |w| close to 1 (or more).
    """
    m = len(near_winding)
    if m == 0:
        return
    needed = max(1, int(np.ceil(min_fraction * m)))
    inside = int((np.abs(near_winding) > 0.75).sum())
    if inside < needed:
        raise UserInputError(
            f"mesh encloses no volume: only {inside} of {m} near-surface samples are clearly inside "
            f"(need {needed}); is it a closed surface?"
        )


# ---------------------------------------------------------------------------
# cache


def _cache_key(v: np.ndarray, f: np.ndarray, config: SdfSamplingConfig) -> str:
    h = hashlib.sha256()
    h.update(f"real2sim-sdf-v{_CACHE_FORMAT}".encode())
    h.update(np.asarray(v.shape, dtype=np.int64).tobytes())
    h.update(v.tobytes())
    h.update(np.asarray(f.shape, dtype=np.int64).tobytes())
    h.update(f.tobytes())
    h.update(repr(sorted(dataclasses.asdict(config).items())).encode())
    return h.hexdigest()[:32]


def _load_cache(path: Path) -> SdfSamples | None:
    if not path.is_file():
        return None
    try:
        with np.load(path) as data:
            return SdfSamples(
                points=data["points"],
                sdf=data["sdf"],
                centre_m=data["centre_m"],
                scale_m=float(data["scale_m"]),
                num_surface=int(data["num_surface"]),
                from_cache=True,
            )
    except Exception:  # a truncated or foreign file: recompute and overwrite it
        return None


def _save_cache(path: Path, samples: SdfSamples) -> None:
    from real2sim.plumbing.outputs import atomic_file

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(path) as tmp, open(tmp, "wb") as fh:  # a reader never sees half a file
            np.savez(
                fh,
                points=samples.points,
                sdf=samples.sdf,
                centre_m=samples.centre_m,
                scale_m=np.float64(samples.scale_m),
                num_surface=np.int64(samples.num_surface),
            )
    except OSError:
        pass  # the cache is an optimisation: an unwritable folder must not fail the stage


class _Steps:
    """The stage's steps as counted progress: sampling, distances and signs, signs."""

    _NAMES = ("sampling", "distances and signs", "signs")

    def __init__(self, progress: ProgressFn | None) -> None:
        self.progress = progress or null_progress
        self.done = 0

    def __enter__(self) -> "_Steps":
        self.progress(f"sdf: {self._NAMES[0]}", 0, len(self._NAMES))
        return self

    def advance(self, name: str) -> None:
        self.done += 1
        self.progress(f"sdf: {name}", self.done, len(self._NAMES))

    def __exit__(self, *exc) -> None:
        if exc[0] is None:
            self.progress("sdf: sampled", len(self._NAMES), len(self._NAMES))
