"""The primitive fitter (paper IV-C3): a union of primitive SDFs fitted to signed-distance samples.
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "FitConfig": "fitting",
    "FitResult": "fitting",
    "fit_collision": "fitting",
    "fit_primitives": "fitting",
    "to_collision_geometry": "fitting",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
