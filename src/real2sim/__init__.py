"""real2sim: turn a real object into a dynamically accurate, fast simulation asset, and measure both.

The front door (:mod:`real2sim.api`), loaded on first use so that ``import real2sim`` stays light::

    import real2sim
    asset = real2sim.build_asset("can.obj", "can_asset", mass_kg=0.4, collision=["cylinders:10", "coacd"])
    asset.model_for("drake")            # can_asset/cylinders_10/model.urdf
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from real2sim.plumbing.version import __version__

if TYPE_CHECKING:  # what IDEs and type checkers see; at run time the names load on first use
    from real2sim.api import Asset, Representation, build_asset, evaluate, load_asset, run
    from real2sim.plumbing.errors import UserInputError

_FRONT_DOOR = {
    "build_asset": "real2sim.api",
    "run": "real2sim.api",
    "evaluate": "real2sim.api",
    "load_asset": "real2sim.api",
    "Asset": "real2sim.api",
    "Representation": "real2sim.api",
    "UserInputError": "real2sim.plumbing.errors",
}
__all__ = ["__version__", *_FRONT_DOOR]


def __getattr__(name: str) -> Any:
    module = _FRONT_DOOR.get(name)
    if module is None:
        raise AttributeError(f"module 'real2sim' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)


def __dir__() -> list[str]:
    return sorted(__all__)
