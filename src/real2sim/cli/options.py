"""argparse types that check a value where it is parsed: numbers with ranges, seeds, devices, ports, paths.

A bad value fails inside ``parse_args`` with one line naming the option
(``real2sim asset: error: argument --seed: expected an integer in 0..4294967295, got '-1'``)
and exit status 2, before any heavy import or work. Every numeric option of every verb
uses a :class:`Number` (``tests/cli/test_bad_inputs.py`` fails on a bare ``type=int``
or ``type=float``); its range travels with it (``min_value``, ``max_value``, ...) so that
the tests and the help text (:func:`finish`) read it from the parser itself.

Only the standard library is imported here; ``device`` imports torch only when a CUDA
device is asked for.
"""

from __future__ import annotations

import argparse
import ipaddress
import math
import os
import re
from pathlib import Path

#: Seeds: what numpy, torch and CoACD all accept.
SEED_MAX = 2**32 - 1
#: COLMAP's random seed is a signed 32-bit integer (pycolmap refuses larger ones).
COLMAP_SEED_MAX = 2**31 - 1


def _fmt(value: float, integer: bool = False) -> str:
    if integer or (float(value).is_integer() and abs(value) < 1e6):
        return str(int(value))
    return f"{value:g}"


class Number:
    """argparse type: a finite number (or an integer) within ``[min_value, max_value]``.

    ``min_inclusive`` / ``max_inclusive`` False make the bound exclusive; an infinite
    bound means no bound on that side (the value must still be finite). ``also``:
    extra accepted integers outside the range (``-1`` meaning "no limit").
    """

    def __init__(self, min_value: float, max_value: float, *, integer: bool = False, min_inclusive: bool = True,
                 max_inclusive: bool = True, also: tuple[int, ...] = ()):
        if not min_value <= max_value:
            raise ValueError(f"empty range {min_value}..{max_value}")
        self.min_value, self.max_value = min_value, max_value
        self.integer = integer
        self.min_inclusive, self.max_inclusive = min_inclusive, max_inclusive
        self.also = tuple(also)
        self.__name__ = "integer" if integer else "number"  # argparse names the type in some messages

    def describe(self) -> str:
        """The accepted values, for people: ``1..2000``, ``0 to 255``, ``> 0 and <= 1000``, ``>= 0``."""
        lo, hi, fmt = self.min_value, self.max_value, lambda v: _fmt(v, self.integer)
        if self.integer and math.isfinite(lo) and math.isfinite(hi):
            text = f"{fmt(lo)}..{fmt(hi)}"
        elif math.isfinite(lo) and math.isfinite(hi) and self.min_inclusive and self.max_inclusive:
            text = f"{fmt(lo)} to {fmt(hi)}"
        else:
            parts = []
            if math.isfinite(lo):
                parts.append(f"{'>=' if self.min_inclusive else '>'} {fmt(lo)}")
            if math.isfinite(hi):
                parts.append(f"{'<=' if self.max_inclusive else '<'} {fmt(hi)}")
            text = " and ".join(parts) or "finite"
        if self.also:
            text = " or ".join(fmt(v) for v in self.also) + " or " + text
        return text

    def contains(self, value: float) -> bool:
        if self.integer and value in self.also:
            return True
        if not self.integer and not math.isfinite(value):  # a huge int is finite but overflows float
            return False
        lo_ok = value >= self.min_value if self.min_inclusive else value > self.min_value
        hi_ok = value <= self.max_value if self.max_inclusive else value < self.max_value
        return lo_ok and hi_ok

    def __call__(self, text: str):
        kind = "an integer" if self.integer else "a number"
        if self.integer and self.min_value == 1 and not self.also:
            kind = "a positive integer"
        if not isinstance(text, str):  # argparse passes string defaults through the type; numbers may come too
            text = str(text)
        shown = text if len(text) <= 40 else text[:37] + "..."
        described = self.describe()
        ranged = (".." in described or " to " in described) and " or " not in described
        phrase = f"in {described}" if ranged else described
        try:
            value = int(text, 10) if self.integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {kind} {phrase}, got {shown!r}") from None
        if not self.contains(value):
            raise argparse.ArgumentTypeError(f"expected {kind} {phrase}, got {shown!r}")
        return value

    def __repr__(self) -> str:
        return f"Number({self.describe()}{', integer' if self.integer else ''})"


def number(min_value: float = -math.inf, max_value: float = math.inf, *, integer: bool = False,
           min_inclusive: bool = True, max_inclusive: bool = True, also: tuple[int, ...] = ()) -> Number:
    """A finite number (``integer=True``: an integer) in the range; see :class:`Number`."""
    return Number(min_value, max_value, integer=integer, min_inclusive=min_inclusive, max_inclusive=max_inclusive,
                  also=also)


def integer(min_value: float, max_value: float, *, also: tuple[int, ...] = ()) -> Number:
    """An integer in ``min_value..max_value`` (both included)."""
    return Number(min_value, max_value, integer=True, also=also)


def positive(max_value: float = math.inf, *, max_inclusive: bool = True) -> Number:
    """A finite number > 0 (and <= ``max_value``)."""
    return Number(0.0, max_value, min_inclusive=False, max_inclusive=max_inclusive)


def nonnegative(max_value: float = math.inf) -> Number:
    """A finite number >= 0 (and <= ``max_value``)."""
    return Number(0.0, max_value)




def seed(max_value: int = SEED_MAX) -> Number:
    """A random seed, ``0..max_value`` (default 0..2**32-1)."""
    return integer(0, max_value)


#: A TCP port.
port = integer(1, 65535)
#: Parallel jobs (processes); more than this is a typo, not a machine.
jobs = integer(1, 256)


_DEVICE = re.compile(r"cuda(?::(\d+))?")


def device(text: str) -> str:
    """argparse type: ``cpu``, ``cuda`` or ``cuda:N``; a CUDA device this machine lacks is refused here."""
    value = text.strip()
    if value == "cpu":
        return value
    match = _DEVICE.fullmatch(value)
    if not match:
        raise argparse.ArgumentTypeError(f"expected cpu or cuda (cuda:N for GPU N), got {text!r}")
    import torch  # only when CUDA is asked for: `cpu` stays light

    if not torch.cuda.is_available():
        raise argparse.ArgumentTypeError(f"{value} asked for, but torch sees no CUDA GPU here; use cpu")
    count = torch.cuda.device_count()
    if match.group(1) is not None and int(match.group(1)) >= count:
        raise argparse.ArgumentTypeError(f"{value}: torch sees {count} CUDA device(s), numbered 0..{count - 1}")
    return value


_HOSTNAME = re.compile(r"(?=.{1,253}$)([A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*")


def host(text: str) -> str:
    """argparse type: an interface to listen on: an IP address, a host name, or ``*`` (all interfaces)."""
    value = text.strip()
    if value == "*":
        return value
    try:
        return str(ipaddress.ip_address(value))
    except ValueError:
        pass
    if _HOSTNAME.fullmatch(value) and not value.replace(".", "").isdigit():
        return value
    raise argparse.ArgumentTypeError(f"expected an IP address, a host name or '*', got {text!r}")


def existing_file(text: str) -> Path:
    """argparse type: a path to an existing, readable regular file."""
    if not text:
        raise argparse.ArgumentTypeError("expected a file path, got ''")
    path = Path(text).expanduser()
    if not path.exists():
        from real2sim.plumbing.paths import missing

        raise argparse.ArgumentTypeError(missing(text, "file"))
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text} is not a file")
    if not os.access(path, os.R_OK):
        raise argparse.ArgumentTypeError(f"{text} is not readable (permission denied)")
    return path


def existing_dir(text: str) -> Path:
    """argparse type: a path to an existing, readable folder."""
    if not text:
        raise argparse.ArgumentTypeError("expected a folder path, got ''")
    path = Path(text).expanduser()
    if not path.exists():
        from real2sim.plumbing.paths import missing

        raise argparse.ArgumentTypeError(missing(text, "folder"))
    if not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is not a folder")
    if not os.access(path, os.R_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"{text} is not readable (permission denied)")
    return path


def cache_dir(text: str) -> str:
    """argparse type: ``auto``, or a folder that exists and is writable or can be made (not a file)."""
    if text == "auto":
        return text
    if not text:
        raise argparse.ArgumentTypeError("expected a folder path or 'auto', got ''")
    path = Path(os.path.abspath(Path(text).expanduser()))
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        where = "is a file" if probe == path else f"lies under {probe}, which is a file"
        raise argparse.ArgumentTypeError(f"{text} {where}, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"cannot write in {probe} (permission denied)")
    try:
        name_max = os.pathconf(probe, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255
    if any(len(os.fsencode(part)) > name_max for part in path.parts[1:]):
        raise argparse.ArgumentTypeError(f"{text}: a name in it is longer than the file system allows ({name_max} bytes)")
    return text


class _OneValueStore(argparse._StoreAction):
    """argparse's store, refusing the empty list Python 3.11's argparse stores for ``--opt=--``
    (it drops the ``--`` and never calls the type)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if isinstance(values, list) and self.nargs is None:
            parser.error(f"argument {'/'.join(self.option_strings) or self.dest}: expected one value, got '--'")
        super().__call__(parser, namespace, values, option_string)


def path(text: str) -> Path:
    """argparse type: a path, never empty. ``Path('')`` is ``Path('.')``: ``--out ''`` (an unset shell
    variable) would otherwise write into, or read, the working folder."""
    if not text:
        raise argparse.ArgumentTypeError("expected a path, got '' (an empty path)")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"a path cannot hold a NUL character, got {text!r}")
    return Path(text)


def finish(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Call at the end of a verb's ``register()``: append each numeric option's accepted values to
    its help text (``[allowed: 1..2000]``), make every single-value option refuse ``--opt=--``,
    and every path argument (``type=Path``) refuse an empty path."""
    for action in parser._actions:  # argparse has no public list of a parser's actions
        if type(action) is argparse._StoreAction:
            action.__class__ = _OneValueStore
        if action.type is Path:
            action.type = path
        if isinstance(action.type, Number) and action.help is not argparse.SUPPRESS and "[allowed:" not in (action.help or ""):
            action.help = f"{action.help or ''} [allowed: {action.type.describe()}]".strip()
    return parser


def numeric_actions(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The actions of ``parser`` that take a number: a :class:`Number` type, a bare int/float type,
    or a non-boolean numeric default."""
    out = []
    for action in parser._actions:
        default = action.default
        numeric_default = isinstance(default, (int, float)) and not isinstance(default, bool)
        takes_value = action.nargs != 0
        if takes_value and (isinstance(action.type, Number) or action.type in (int, float) or
                            (numeric_default and action.option_strings)):
            out.append(action)
    return out


# ---------------------------------------------------------------------------------------------
# what a verb does with each path it takes (docs/reliability.md, "What --overwrite never removes")

#: The roles of :func:`declare_paths`. ``reads``: an input, never written, never removed.
#: ``writes``: an output, replaced whole by ``--overwrite``. ``in_place``: a folder the verb edits
#: (its own files only). ``cache``: a folder of reusable results, never replaced.
PATH_ROLES = ("reads", "writes", "in_place", "cache")


def declare_paths(parser: argparse.ArgumentParser, *, reads: tuple[str, ...] = (), writes: tuple[str, ...] = (),
                  in_place: tuple[str, ...] = (), cache: tuple[str, ...] = ()) -> argparse.ArgumentParser:
    """Record, by argparse ``dest``, what ``parser``'s verb does with each path option, so that
    before any work the CLI refuses an output that is, contains or lies inside an input
    (:func:`real2sim.plumbing.outputs.check_outputs_spare_inputs`). ``tests/cli/test_path_roles.py``
    fails when a path option of any verb is left out."""
    actions = {action.dest: action for action in parser._actions}
    roles = {"reads": reads, "writes": writes, "in_place": in_place, "cache": cache}
    table: dict[str, tuple[str, str]] = {}
    for role, dests in roles.items():
        for dest in dests:
            action = actions.get(dest)
            if action is None:
                raise ValueError(f"{parser.prog}: declare_paths names {dest!r}, which is no option of it")
            label = action.option_strings[-1] if action.option_strings else str(action.metavar or dest.upper())
            table[dest] = (role, label)
    parser.set_defaults(path_roles=table)
    return parser


def declared_paths(args: argparse.Namespace, role: str) -> list[tuple[str, Path]]:
    """The ``(option, path)`` pairs of the parsed ``args`` that its verb declared with ``role``
    (see :func:`declare_paths`); options not given are left out, lists give one pair per path."""
    table: dict[str, tuple[str, str]] = getattr(args, "path_roles", None) or {}
    out: list[tuple[str, Path]] = []
    for dest, (its_role, label) in table.items():
        if its_role != role:
            continue
        value = getattr(args, dest, None)
        values = value if isinstance(value, (list, tuple)) else [value]
        out.extend((label, Path(v)) for v in values if v is not None and str(v) != "")
    return out
