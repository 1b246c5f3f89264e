"""The ``real2sim`` command line: a thin shell over the stage modules.

Each verb lives in a ``cli/<verb>.py`` module with ``register(subparsers)``
(argparse only, so ``--help`` is instant) and a ``run(args) -> int`` that imports
the heavy stages lazily. User mistakes raise :class:`UserInputError`, which
becomes one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from real2sim import __version__
from real2sim.formats.errors import UserInputError

# Order is the order of `real2sim --help`.
_VERB_MODULES = ("demo", "objects", "capture", "reconstruct", "asset", "run", "evaluate", "view")


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse, but a usage mistake is one line on stderr (and exit status 2)."""

    def error(self, message: str):  # type: ignore[override]
        print(f"{self.prog}: error: {message} (see --help)", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(
        prog="real2sim",
        description="Turn an object mesh into a dynamically accurate, fast simulation asset "
        "(URDF/SDFormat for Drake), and measure its accuracy and speed. Units are SI.",
    )
    parser.add_argument("--version", action="version", version=f"real2sim {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    for name in _VERB_MODULES:
        try:
            module = importlib.import_module(f"real2sim.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"real2sim.cli.{name}":
                continue  # verb not part of this build
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    if "torch" not in sys.modules:
        # Torch's default OpenMP spin-wait stalls small ops on 2 busy cores (DESIGN.md): the quick demo
        # took 5 min with it and under 2 with PASSIVE. Set here, by the program, before torch loads;
        # worker processes inherit it. A value the user set wins.
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except UserInputError as exc:
        print(f"real2sim {args.verb}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("real2sim: interrupted", file=sys.stderr)
        return 130


# argparse types of numbers with ranges live in cli/options.py; these two names stay importable from here.
from real2sim.cli.options import positive_float, positive_int  # noqa: E402,F401
