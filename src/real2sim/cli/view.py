"""`real2sim view`: show an asset's visual and collision geometry in Drake's Meshcat."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser(
        "view",
        help="show an asset in the browser (Drake's Meshcat): visual and collision geometry",
        description="Loads ASSETDIR/<representation>/model.urdf into a Drake MultibodyPlant and serves it "
        "with Meshcat on localhost; open the printed URL. Illustration (visual) and proximity (collision) "
        "layers can be toggled in Meshcat's menu. Ctrl-C stops.",
    )
    p.add_argument("asset", type=Path, metavar="ASSETDIR")
    p.add_argument("--representation", help="representation folder to show (default: the first)")
    p.add_argument("--port", type=int, default=None, help="Meshcat port (default: Drake's, 7000 or next free)")
    p.add_argument("--seconds", type=float, default=None, help="serve this long then exit (default: until Ctrl-C)")
    p.set_defaults(func=run)


def representation_urdfs(asset_dir: Path) -> list[Path]:
    """The model.urdf of every representation folder of an asset, sorted by name."""
    from real2sim.formats.errors import UserInputError

    if not asset_dir.is_dir():
        raise UserInputError(f"asset folder not found: {asset_dir}")
    urdfs = sorted(asset_dir.glob("*/model.urdf"))
    if not urdfs:
        raise UserInputError(f"{asset_dir} holds no representation (no */model.urdf)")
    return urdfs


def run(args: argparse.Namespace) -> int:
    import time

    from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams, Role, StartMeshcat
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    from real2sim.formats.errors import UserInputError

    urdfs = representation_urdfs(args.asset)
    if args.representation:
        urdfs = [u for u in urdfs if u.parent.name == args.representation]
        if not urdfs:
            raise UserInputError(f"no representation {args.representation!r} in {args.asset}")
    urdf = urdfs[0]
    meshcat = StartMeshcat() if args.port is None else __import__("pydrake.geometry", fromlist=["Meshcat"]).Meshcat(args.port)
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    Parser(plant).AddModels(str(urdf))
    plant.Finalize()
    for role, prefix in ((Role.kIllustration, "visual"), (Role.kProximity, "collision")):
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(role=role, prefix=prefix))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    diagram.ForcedPublish(context)
    print(f"showing {urdf} at {meshcat.web_url()}  (Ctrl-C to stop)", flush=True)
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    try:
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    return 0
