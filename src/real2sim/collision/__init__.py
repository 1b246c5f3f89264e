"""Collision geometry from a canonical mesh: SDF sampling, primitive SDFs, superquadrics,
the primitive fitter (:mod:`.fit`), convex decomposition baselines and particles.

A sub-stage of :mod:`real2sim.asset`: the asset stage calls it; it never calls back.
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "FitConfig": "fit",
    "FitResult": "fit",
    "fit_collision": "fit",
    "fit_primitives": "fit",
    "SdfSamplingConfig": "sdf_sampling",
    "SdfSamples": "sdf_sampling",
    "sample_sdf": "sdf_sampling",
    "CoacdConfig": "decomposition",
    "VhacdConfig": "decomposition",
    "decompose": "decomposition",
    "particle_spheres": "particles",
    "particles_for_count": "particles",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
