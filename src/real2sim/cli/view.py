"""`real2sim view`: show an asset's visual and collision geometry in Drake's Meshcat."""

from __future__ import annotations

import argparse
from pathlib import Path

from real2sim.cli import options


def register(sub) -> None:
    p = sub.add_parser(
        "view",
        help="show an asset in the browser (Drake's Meshcat): visual and collision geometry",
        description="Loads ASSETDIR/<representation>/model.urdf into a Drake MultibodyPlant and serves it "
        "with Meshcat on this machine only (127.0.0.1) unless --host says otherwise; open the printed URL. "
        "Illustration (visual) and proximity (collision) layers can be toggled in Meshcat's menu. Ctrl-C stops.",
    )
    p.add_argument("asset", type=Path, metavar="ASSETDIR")
    p.add_argument("--representation", help="representation folder to show (default: the first)")
    p.add_argument("--host", type=options.host, default="127.0.0.1",
                   help="interface to listen on (default 127.0.0.1: this machine only; '*' or 0.0.0.0: every "
                   "interface, so that other machines can connect)")
    p.add_argument("--port", type=options.port, default=None,
                   help="Meshcat port (default: Drake's, 7000 or the next free one up to 7099)")
    p.add_argument("--duration-s", type=options.nonnegative(1.0e6), default=None, metavar="S",
                   help="serve this long then exit, s (default: until Ctrl-C)")
    options.finish(p)
    options.declare_paths(p, reads=("asset",))
    p.set_defaults(func=run)


def representation_urdfs(asset_dir: Path) -> list[Path]:
    """The model.urdf of every representation folder of an asset, sorted by name."""
    from real2sim.plumbing.errors import UserInputError

    if not asset_dir.is_dir():
        from real2sim.plumbing.paths import missing

        if asset_dir.exists():
            raise UserInputError(f"{asset_dir} is a file, not an asset folder")
        raise UserInputError(missing(asset_dir, "asset folder"))
    urdfs = sorted(asset_dir.glob("*/model.urdf"))
    if not urdfs:
        raise UserInputError(f"{asset_dir} holds no representation (no */model.urdf)")
    return urdfs


def _first_line(exc: BaseException) -> str:
    """The first line of Drake's message, without its ``FILE:LINE: error:`` prefix."""
    import re

    text = str(exc).strip()
    line = text.splitlines()[0] if text else type(exc).__name__
    return re.sub(r"^\S*:\d+: error: ", "", line)


def load_model(urdf: Path):
    """(builder, scene_graph) holding the model at ``urdf`` in a finalized plant; UserInputError
    (one line) when Drake cannot load it (malformed URDF, a mesh that is missing or unreadable)."""
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    from real2sim.plumbing.errors import UserInputError

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    try:
        Parser(plant).AddModels(str(urdf))
        plant.Finalize()
    except (RuntimeError, ValueError) as exc:  # Drake reports parse and mesh errors as RuntimeError
        raise UserInputError(f"cannot load {urdf}: {_first_line(exc)}") from None
    return builder, scene_graph


#: How long a --host name may take to resolve, s: a name the resolver cannot answer otherwise
#: stalls Drake's server for minutes before it says anything.
RESOLVE_TIMEOUT_S = 5.0
#: Addresses that mean "every interface": a browser cannot open them.
_ANY_ADDRESS = ("*", "0.0.0.0", "::")


def resolve_host(host: str, timeout_s: float = RESOLVE_TIMEOUT_S, resolve=None) -> str:
    """The numeric address to listen on for ``host`` (``*`` stays ``*``); UserInputError (one line)
    when the name does not resolve, or not within ``timeout_s``.

    The resolver runs in a daemon thread that the main thread waits for with a timeout: a system
    resolver that never answers cannot stall the command, and SIGTERM or Ctrl-C (handled in the
    main thread) still stop it while it waits. ``resolve``: the resolver, ``socket.getaddrinfo`` by
    default (a parameter so that a stalled one can be tried).
    """
    import ipaddress
    import socket
    import threading

    from real2sim.plumbing.errors import UserInputError

    if host == "*":
        return host
    try:
        return str(ipaddress.ip_address(host))
    except ValueError:
        pass
    resolve = resolve or socket.getaddrinfo
    found: list = []

    def work() -> None:
        try:
            found.append(resolve(host, None, type=socket.SOCK_STREAM))
        except (OSError, UnicodeError) as exc:  # socket.gaierror is an OSError
            found.append(exc)

    worker = threading.Thread(target=work, name="real2sim-resolve-host", daemon=True)
    worker.start()
    worker.join(timeout_s)
    if not found:
        raise UserInputError(f"--host {host}: the name did not resolve within {timeout_s:g} s; "
                             "pass an IP address (127.0.0.1: this machine only)")
    if isinstance(found[0], BaseException) or not found[0]:
        raise UserInputError(f"--host {host}: no such host (the name does not resolve); pass an IP address "
                             "or a name of this machine")
    # IPv4 first: Drake's server and most browsers' "localhost" meet there.
    addresses = sorted({info[4][0] for info in found[0]}, key=lambda a: ":" in a)
    return addresses[0]


def browser_urls(host: str, port: int) -> tuple[str, str | None]:
    """(the URL to open on this machine, a note for other machines or None) for a server on
    ``host`` (as the user gave it) and ``port``. An every-interface address is not a place a
    browser can go: point at localhost and name this machine for the others."""
    import socket

    if host in _ANY_ADDRESS:
        return (f"http://localhost:{port}",
                f"listening on all interfaces; from another machine open http://{socket.gethostname()}:{port}")
    shown = f"[{host}]" if ":" in host else host
    return f"http://{shown}:{port}", None


def start_meshcat(host: str, port: int | None, address: str | None = None):
    """Drake's Meshcat on ``host`` (``port`` None: the first free of 7000..7099); UserInputError
    when it cannot listen there (port in use, not allowed, or no such interface). ``address``:
    ``host`` already resolved; None resolves it here, with a bounded wait (:func:`resolve_host`)."""
    from pydrake.geometry import Meshcat, MeshcatParams

    from real2sim.plumbing.errors import UserInputError

    address = address or resolve_host(host)
    try:
        return Meshcat(MeshcatParams(host=address, port=port))
    except RuntimeError:
        if port is None:
            raise UserInputError(f"cannot listen on {host}, ports 7000..7099 (all in use, or no such interface); "
                                 "pass a free --port or another --host") from None
        raise UserInputError(f"--port {port}: cannot listen on {host}:{port} (port in use, not allowed, or no such "
                             "interface); pass a free --port or another --host") from None


def run(args: argparse.Namespace) -> int:
    import time

    from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams, Role

    from real2sim.plumbing.errors import UserInputError

    urdfs = representation_urdfs(args.asset)
    if args.representation:
        urdfs = [u for u in urdfs if u.parent.name == args.representation]
        if not urdfs:
            raise UserInputError(f"no representation {args.representation!r} in {args.asset}")
    urdf = urdfs[0]
    if not urdf.is_file():  # a FIFO would keep Drake's parser waiting for a writer forever
        raise UserInputError(f"{urdf} is not a regular file")
    address = resolve_host(args.host)  # before the model: a name that does not resolve fails at once
    builder, scene_graph = load_model(urdf)  # a model Drake cannot load fails here, before a port is opened
    meshcat = start_meshcat(args.host, args.port, address)
    for role, prefix in ((Role.kIllustration, "visual"), (Role.kProximity, "collision")):
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(role=role, prefix=prefix))
    diagram = builder.Build()
    try:
        diagram.ForcedPublish(diagram.CreateDefaultContext())
    except RuntimeError as exc:
        raise UserInputError(f"cannot show {urdf}: {_first_line(exc)}") from None
    url, note = browser_urls(args.host, meshcat.port())
    print(f"showing {urdf} at {url}  (Ctrl-C to stop)", flush=True)
    if note:
        print(note, flush=True)
    deadline = None if args.duration_s is None else time.monotonic() + args.duration_s
    try:
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2)
    except KeyboardInterrupt as exc:  # Ctrl-C is how a user stops the server: a normal end
        from real2sim.cli import Terminated

        if isinstance(exc, Terminated):  # SIGTERM is not: exit 143, as every verb does
            raise
    return 0
