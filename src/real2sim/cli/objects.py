"""`real2sim objects`: list the bundled objects, or export one as a textured OBJ."""

from __future__ import annotations

import argparse
from pathlib import Path

from real2sim.cli import options


def register(sub) -> None:
    p = sub.add_parser(
        "objects",
        help="list the bundled objects, or export one as a textured mesh",
        description="Bundled objects are made by code (no downloads): a mustard-like squeeze bottle, "
        "a soup can, and the shape set (a mug upright and on its side, a bowl, an L-bracket, a hammer, "
        "a torus, a banana, a gear, a stool). `real2sim objects` lists them with their suggested mass and "
        "the chord error of their round parts; "
        "`real2sim objects export NAME PATH.obj` writes one (OBJ + MTL + PNG, metres, standing on z = 0).",
    )
    p.add_argument("action", nargs="?", choices=["list", "export"], default="list")
    p.add_argument("name", nargs="?", help="object to export (see `real2sim objects`)")
    p.add_argument("path", nargs="?", type=Path, help="output .obj path")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    p.set_defaults(func=run)
    options.declare_paths(p, writes=("path",))


def run(args: argparse.Namespace) -> int:
    from real2sim.plumbing.errors import UserInputError
    from real2sim.geometry.objects import OBJECTS, listing

    if args.action == "list":
        print("\n".join(listing()))
        return 0
    if not args.name or not args.path:
        raise UserInputError("usage: real2sim objects export NAME PATH.obj")
    if args.name not in OBJECTS:
        raise UserInputError(f"unknown bundled object {args.name!r}; known: {', '.join(OBJECTS)}")
    from real2sim.geometry.mesh_io import textured_mesh_files
    from real2sim.plumbing.outputs import check_output_path, write_bytes_atomic
    from real2sim.geometry.objects import make_textured_object

    path = check_output_path(args.path, what="export")
    if path.suffix.lower() != ".obj":
        raise UserInputError(f"export path must end in .obj, got {path}")
    files = textured_mesh_files(make_textured_object(args.name), path)
    targets = [path.parent / name for name in files]
    for target in targets:
        if target.is_dir():
            raise UserInputError(f"{target} is a folder; the export needs a file there")
    existing = [t.name for t in targets if t.exists()]
    if existing and not args.overwrite:
        raise UserInputError(f"{', '.join(existing)} already exist in {path.parent}; pass --overwrite to replace them")
    path.parent.mkdir(parents=True, exist_ok=True)
    for target in targets[1:] + targets[:1]:  # the OBJ last: it is complete only when its files are
        write_bytes_atomic(target, files[target.name])
    mass = OBJECTS[args.name].mass_kg
    print(f"wrote {path} and {', '.join(t.name for t in targets[1:])} "
          f"({mass} kg suggested: real2sim asset {path} --mass-kg {mass} ...)")
    return 0
