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
import warnings
from pathlib import Path

from real2sim.plumbing.version import __version__
from real2sim.cli import options
from real2sim.cli.extras import check_extras
from real2sim.cli.options import integer
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.inputs import check_outputs_spare_inputs
from real2sim.plumbing.temporary_names import public_paths

#: --threads: torch CPU threads; the environment variable that gives the default.
THREADS = integer(1, 1024)
THREADS_ENV = "REAL2SIM_THREADS"

# Order is the order of `real2sim --help`.
_VERB_MODULES = ("demo", "objects", "capture", "board", "reconstruct", "asset", "run", "batch", "excite", "identify",
                 "evaluate", "view")


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
    for verb_parser in sub.choices.values():  # also for a verb whose register() does not call options.finish
        for action in verb_parser._actions:
            if action.type is Path:
                action.type = options.path  # '' is not the working folder
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
    terminated: list[int] = []

    def on_sigterm(signum, frame) -> None:
        terminated.append(signum)
        raise Terminated()

    previous_sigterm = signal.signal(signal.SIGTERM, on_sigterm) if _in_main_thread() else None
    keeper = _SigtermKeeper() if previous_sigterm is not None else None
    if keeper is not None:
        sys.meta_path.insert(0, keeper)
    try:
        # every output against every input the verb declared, before any import or work (docs/reliability.md)
        check_outputs_spare_inputs(options.declared_paths(args, "writes"), options.declared_paths(args, "reads"))
        check_extras(args)
        set_torch_threads(args.threads)
        with warnings.catch_warnings():  # the filters and the display are put back when the command ends
            warnings.showwarning = _plain_warning
            for message, module in _EXPECTED_WARNINGS:
                warnings.filterwarnings("ignore", message=message, category=RuntimeWarning, module=module)
            code = int(args.func(args) or 0)
        # a verb that catches Ctrl-C itself (to say what it kept) returns 130; a SIGTERM stays a SIGTERM
        return 128 + signal.SIGTERM if terminated and code == 130 else code
    except UserInputError as exc:
        print(f"real2sim {args.verb}: error: {public_paths(str(exc))}", file=sys.stderr)
        if getattr(exc, "exit_now", False):  # a library call was abandoned mid-way (executors.init_ray_bounded)
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(2)
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
            where = public_paths(str(exc.filename)) if exc.filename else "the output"
            print(f"real2sim {args.verb}: error: {os.strerror(exc.errno).lower()} while writing "
                  f"{where}; no partial output was published", file=sys.stderr)
            return 1
        loop = _link_loop(exc)
        if loop is not None:  # a user's file system, not a bug: wherever a path was resolved
            print(f"real2sim {args.verb}: error: {loop}", file=sys.stderr)
            return 2
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        # a temporary path in the message was removed on the way out: name the output instead
        first = public_paths(first)
        print(f"real2sim {args.verb}: internal error: {type(exc).__name__}: {first[:300]} "
              "(run `real2sim --debug ...` for the traceback, and please report it)", file=sys.stderr)
        return 1
    finally:
        if keeper is not None and keeper in sys.meta_path:
            sys.meta_path.remove(keeper)
        if previous_sigterm is not None:
            signal.signal(signal.SIGTERM, previous_sigterm)


_DISK_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)

#: (message, module) regular expressions of warnings that are expected and say nothing to a user.
#: trimesh divides by a part's volume for its centre of mass: the zero-volume scraps of a voxel
#: surface (parallax masks, visual hulls) give NaN centres that nobody reads; only volumes are used.
_EXPECTED_WARNINGS = (("invalid value encountered in divide", r"trimesh\."),)


def _plain_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A Python warning that reaches the command line, as one plain ``WARNING: ...`` line on
    stderr: the source file and line that Python prints with it mean nothing to a user."""
    text = " ".join(str(message).split())
    print(f"WARNING: {text}", file=file or sys.stderr, flush=True)


def _link_loop(exc: BaseException) -> str | None:
    """The one-line message for a symbolic link loop met anywhere (``Path.resolve`` raises a
    RuntimeError for it in Python 3.11, the system calls OSError ELOOP), else None."""
    if isinstance(exc, OSError) and exc.errno == errno.ELOOP:
        return f"{exc.filename or 'a path'}: a symbolic link loop (a link that points back to itself)"
    text = str(exc)
    if type(exc) is RuntimeError and text.startswith("Symlink loop from "):
        return f"{text[len('Symlink loop from '):].strip(chr(39))}: a symbolic link loop (a link that points back to itself)"
    return None


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


class _SigtermKeeper:
    """Import hook: after a library that takes over SIGTERM at import has loaded, give SIGTERM back
    to the handler Python has on record (the one :func:`main` installs while a command runs).

    pycolmap installs glog's crash handler when it loads, SIGTERM included, behind Python's back:
    ``signal.getsignal`` still names our handler, but a SIGTERM then printed a 30-line native stack
    dump and killed the process, leaving the dataset's lock and COLMAP's temporary folder behind.
    The libraries are imported lazily by the stages, so the CLI restores SIGTERM where they load.
    """

    TAKE_SIGTERM = ("pycolmap",)

    def find_spec(self, name, path=None, target=None):
        if name not in self.TAKE_SIGTERM:
            return None
        import importlib.util

        sys.meta_path.remove(self)  # find the real spec without finding ourselves again
        try:
            spec = importlib.util.find_spec(name)
        finally:
            sys.meta_path.insert(0, self)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        spec.loader = _RestoreSigtermLoader(spec.loader)
        return spec


class _RestoreSigtermLoader:
    """A module loader that runs ``inner`` and then re-installs Python's SIGTERM handler."""

    def __init__(self, inner):
        self.inner = inner

    def create_module(self, spec):
        return self.inner.create_module(spec)

    def exec_module(self, module) -> None:
        try:
            self.inner.exec_module(module)
        finally:
            if _in_main_thread():
                signal.signal(signal.SIGTERM, signal.getsignal(signal.SIGTERM))

    def __getattr__(self, name):  # get_resource_reader, is_package, ...: the real loader's
        return getattr(self.inner, name)


def _in_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()
