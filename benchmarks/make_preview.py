"""The README's picture: the bundled mug as `real2sim asset` builds it, its visual mesh beside the
collision geometry of three representations (docs/images/preview.png).

    python benchmarks/make_preview.py [--out docs/images/preview.png]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import real2sim
from real2sim.cli import main as cli
from real2sim.report.preview import write_asset_preview

ROOT = Path(__file__).resolve().parents[1]
SPECS = ["ellipsoids:16", "cylinders:10", "coacd"]


def make(out: Path) -> None:
    with tempfile.TemporaryDirectory() as work:
        mesh = Path(work) / "mug.obj"
        assert cli(["objects", "export", "mug", str(mesh)]) == 0
        asset = real2sim.build_asset(mesh, Path(work) / "mug_asset", mass_kg=0.35, collision=SPECS, )
        names = [rep.name for rep in asset.representations]
        if not write_asset_preview(asset.folder, out, names, panel_px=240):
            raise SystemExit("the asset has no visual mesh to show")
    print(f"wrote {out}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "preview.png")
    make(parser.parse_args().out)
