"""Which optional extra each verb needs, checked before any work: a missing one is one line naming
the ``pip install`` that brings it, not an ImportError from deep inside a stage."""

from __future__ import annotations

import argparse
import importlib.util

from real2sim.plumbing.errors import UserInputError

#: extra -> the modules it brings (what ``import`` names), in pyproject.toml's [project.optional-dependencies].
EXTRA_MODULES: dict[str, tuple[str, ...]] = {
    "sim": ("pydrake", "matplotlib"),
    "reconstruct": ("open3d", "xatlas"),
    "phone": ("pycolmap", "cv2", "av"),
    "batch": ("ray",),
    "usd": ("pxr",),
    "mujoco": ("mujoco",),
}

#: verb -> the extras it always needs. `asset` needs none: mesh -> asset is the core install.
VERB_EXTRAS: dict[str, tuple[str, ...]] = {
    "demo": ("sim", "reconstruct"),
    "capture": ("sim",),
    "refine-poses": ("phone",),
    "board": ("phone",),
    "reconstruct": ("reconstruct",),
    "run": ("reconstruct",),
    "batch": ("reconstruct",),
    "excite": ("sim",),
    "identify": ("sim",),
    "evaluate": ("sim",),
    "report": ("sim",),
    "view": ("sim",),
}


def extras_needed(args: argparse.Namespace) -> list[str]:
    """The extras the parsed command needs: its verb's, and those its options ask for."""
    needed = list(VERB_EXTRAS.get(args.verb, ()))
    if "usd" in (getattr(args, "formats", None) or []):
        needed.append("usd")
    if getattr(args, "executor", None) == "ray":
        needed.append("batch")
    if getattr(args, "evaluate", False):
        needed.append("sim")
    if getattr(args, "handheld", False):
        needed.append("phone")
    return list(dict.fromkeys(needed))


def missing_module(extra: str) -> str | None:
    """The first module of ``extra`` that is not installed, or None."""
    for module in EXTRA_MODULES[extra]:
        try:
            found = importlib.util.find_spec(module)
        except (ImportError, ValueError):  # a broken or hidden installation counts as missing
            found = None
        if found is None:
            return module
    return None


def check_extras(args: argparse.Namespace) -> None:
    """UserInputError (one line, exit 2) when an extra the command needs is not installed."""
    for extra in extras_needed(args):
        module = missing_module(extra)
        if module is not None:
            raise UserInputError(f"{args.verb} needs the [{extra}] extra ({module} is not installed): "
                                 f"pip install 'real2sim[{extra}]'")
