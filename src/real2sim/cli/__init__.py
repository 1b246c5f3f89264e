"""The ``real2sim`` command line: a thin shell over the stage modules.

Each verb lives in a ``cli/<verb>.py`` module with ``register(subparsers)``
(argparse only, so ``--help`` is instant) and a ``run(args) -> int`` that imports
the heavy stages lazily. User mistakes raise :class:`UserInputError`, which
becomes one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import signal
import sys

from real2sim import __version__
from real2sim.cli.options import integer
from real2sim.formats.errors import UserInputError

#: --threads: torch CPU threads; the environment variable that gives the default.
THREADS = integer(1, 1024)
THREADS_ENV = "REAL2SIM_THREADS"

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
    parser.add_argument("--debug", action="store_true",
                        help="on an internal error, print the whole traceback (default: one line)")
    parser.add_argument("--threads", type=THREADS, default=None, metavar="N",
                        help=f"torch CPU threads for the whole command (default: ${THREADS_ENV}, else torch's own "
                        f"choice) [allowed: {THREADS.describe()}]")
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
    previous_sigterm = signal.signal(signal.SIGTERM, _terminate) if _in_main_thread() else None
    try:
        set_torch_threads(args.threads)
        return int(args.func(args) or 0)
    except UserInputError as exc:
        print(f"real2sim {args.verb}: error: {exc}", file=sys.stderr)
        return 2
    except Terminated:
        print("real2sim: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print("real2sim: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.debug:
            raise
        if isinstance(exc, OSError) and exc.errno in _DISK_FULL:
            # Not a bug: the outputs are written whole or not at all, so say so and stop.
            print(f"real2sim {args.verb}: error: {os.strerror(exc.errno).lower()} while writing "
                  f"{exc.filename or 'the output'}; no partial output was published", file=sys.stderr)
            return 1
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        print(f"real2sim {args.verb}: internal error: {type(exc).__name__}: {first[:300]} "
              "(run `real2sim --debug ...` for the traceback, and please report it)", file=sys.stderr)
        return 1
    finally:
        if previous_sigterm is not None:
            signal.signal(signal.SIGTERM, previous_sigterm)


_DISK_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def set_torch_threads(threads: int | None) -> None:
    """The program's one choice of torch's CPU threads: ``--threads``, else ``$REAL2SIM_THREADS``,
    else torch's default. The stages use what they are given and never change it."""
    if threads is None:
        text = os.environ.get(THREADS_ENV, "").strip()
        if not text:
            return
        try:
            threads = THREADS(text)
        except argparse.ArgumentTypeError as exc:
            raise UserInputError(f"${THREADS_ENV}: {exc}") from None
    import torch

    torch.set_num_threads(int(threads))


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is, so that the same clean-up as Ctrl-C runs
    (temporary folders removed, worker pools stopped, finished results kept)."""


def _terminate(signum, frame) -> None:
    raise Terminated()


def _in_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


# argparse types of numbers with ranges live in cli/options.py; these two names stay importable from here.
from real2sim.cli.options import positive_float, positive_int  # noqa: E402,F401
