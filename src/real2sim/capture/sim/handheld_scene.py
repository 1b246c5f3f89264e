"""The scene and the camera of a simulated handheld phone capture (:mod:`real2sim.capture.sim.handheld`): the
object on a textured table with the printed board or square markers under it, a room behind it when asked,
rendered through a phone's lens.

World frame: the board's (its centre the origin, the paper z = 0, z up, metres); without a board the table
top is z = 0.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from real2sim.capture.phone.board import board_centre_on_page_dots, page_image
from real2sim.capture.phone.media import LensWarp, motion_blur
from real2sim.capture.sim.capture_output import save_png
from real2sim.capture.sim.handheld_config import HandheldConfig
from real2sim.capture.sim.printed_markers import MarkerLayout, marker_page
from real2sim.capture.sim.render_scene import ROOM_LABEL, TABLE_LABEL, RenderScene
from real2sim.capture.sim.room import ATLAS, clutter_mesh, room_parts, room_textures
from real2sim.capture.sim.textures import export_textured_obj, procedural_texture
from real2sim.formats.dataset import CV_FROM_GL, CameraIntrinsics

#: The table top lies this far under the paper (z = 0), metres: a sheet's thickness, enough for the
#: depth buffer to keep the two apart.
PAPER_THICKNESS_M = 0.0002
#: Resolution of the board's texture on the table, dots per mm.
BOARD_TEXTURE_DOTS_PER_MM = 6
#: Printed paper is not a perfect white nor ink a perfect black under room light (0-255).
PAPER_WHITE, INK_BLACK = 236, 28


def _textured_quad_obj(path: Path, size_m: tuple[float, float], z_m: float, texture_png: Path) -> Path:
    """An OBJ of one upward-facing rectangle centred on the origin at height ``z_m``, its texture's
    top row towards +y (the printed page's top edge, as the board frame has it)."""
    w, h = size_m[0] / 2, size_m[1] / 2
    path.write_text(
        f"mtllib {path.stem}.mtl\nusemtl paper\n"
        f"v {-w} {-h} {z_m}\nv {w} {-h} {z_m}\nv {w} {h} {z_m}\nv {-w} {h} {z_m}\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nf 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n")
    path.with_suffix(".mtl").write_text(f"newmtl paper\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nmap_Kd {texture_png.name}\n")
    return path


def _add_anchored(scene: RenderScene, shape, pose_m: np.ndarray, name: str, label: int, diffuse_map: Path | None,
                  colour: tuple[float, float, float] | None = None) -> None:
    """Add a visible (perception) shape fixed in the world to an already built scene, textured by
    ``diffuse_map`` or plain ``colour`` (RGB 0-1)."""
    from pydrake.geometry import GeometryInstance, PerceptionProperties, RenderLabel, Rgba
    from pydrake.math import RigidTransform

    geom = GeometryInstance(RigidTransform(pose_m), shape, name)
    props = PerceptionProperties()
    props.AddProperty("label", "id", RenderLabel(label))
    if diffuse_map is not None:
        props.AddProperty("phong", "diffuse_map", str(diffuse_map))
    elif colour is not None:
        props.AddProperty("phong", "diffuse", Rgba(*colour, 1.0))
    geom.set_perception_properties(props)
    scene.sg.RegisterGeometry(scene.sg_context, scene.source, scene.sg.world_frame_id(), geom)


def _add_room(scene: RenderScene, config: HandheldConfig, work: Path) -> None:
    """The walls and floor of :func:`real2sim.capture.sim.room.room_parts`, and its shelves and things as one
    textured mesh (:func:`real2sim.capture.sim.room.clutter_mesh`)."""
    import trimesh
    from PIL import Image
    from pydrake.geometry import Box, Mesh

    textures = room_textures(work, config.texture_seed)
    parts = room_parts(config.table_size_m, config.texture_seed)
    big = [p for p in parts if p.texture is not None and p.texture < ATLAS]
    for part in big:
        _add_anchored(scene, Box(*part.size_m), part.pose_m, part.name, ROOM_LABEL, textures[part.texture])
    mesh, uv = clutter_mesh([p for p in parts if p not in big], config.texture_seed)
    with Image.open(textures[ATLAS]) as atlas:
        mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=atlas.convert("RGB"))
    obj = export_textured_obj(mesh, work / "room" / "clutter.obj")
    _add_anchored(scene, Mesh(str(obj)), np.eye(4), "room_clutter", ROOM_LABEL, None)


def _add_markers(scene: RenderScene, layout: MarkerLayout, work: Path) -> None:
    """Each marker's printed sheet lying on the table (z = 0)."""
    from pydrake.geometry import Mesh

    for marker_id, pose in zip(layout.ids, layout.sheet_poses):
        png = work / f"marker{int(marker_id)}.png"
        save_png(png, marker_page(layout.dictionary, int(marker_id), PAPER_WHITE, INK_BLACK))
        quad = _textured_quad_obj(work / f"marker{int(marker_id)}.obj", (layout.sheet_side_m,) * 2, 0.0, png)
        _add_anchored(scene, Mesh(str(quad)), pose, f"marker{int(marker_id)}", TABLE_LABEL, None)


def build_handheld_scene(config: HandheldConfig, mesh_obj: Path, world_from_mesh: np.ndarray, work: Path,
                         cam: CameraIntrinsics, far_m: float, markers: MarkerLayout | None = None) -> RenderScene:
    """The object on a textured table, with the printed board under it when ``config.board``, the printed
    ``markers`` around it, and the room of :mod:`real2sim.capture.sim.room` when ``config.room``."""
    from pydrake.geometry import Box, Mesh

    # No table from RenderScene: ours sits a sheet's thickness lower, so that the paper is z = 0.
    scene = RenderScene(mesh_obj, world_from_mesh, None, config.table_size_m, cam, stand_m=None, far_m=far_m)
    table_png = work / "table_texture.png"
    # beyond the default size, the table gets the grain a close-up needs (mm-scale detail)
    save_png(table_png, procedural_texture(int(config.table_texture_px), config.texture_seed,
                                           grain=config.table_texture_px > 2048))
    top_m = -PAPER_THICKNESS_M if config.board is not None or markers is not None else 0.0
    thickness = 0.04
    pose = np.eye(4)
    pose[2, 3] = top_m - thickness / 2
    _add_anchored(scene, Box(config.table_size_m, config.table_size_m, thickness), pose, "table", TABLE_LABEL, table_png)
    if config.board is not None:
        page = page_image(config.board, "a4", BOARD_TEXTURE_DOTS_PER_MM)
        page = (INK_BLACK + (PAPER_WHITE - INK_BLACK) * (page.astype(float) / 255.0)).astype(np.uint8)
        page_png = work / "board_page.png"
        save_png(page_png, np.repeat(page[:, :, None], 3, axis=2))
        # Metres per texture dot from the squares themselves (a whole number of dots each), so that
        # the rendered squares are exactly ``square_m`` whatever the rounding of the page.
        m_per_dot = config.board.square_m / round(config.board.square_m * 1000.0 * BOARD_TEXTURE_DOTS_PER_MM)
        offset = board_centre_on_page_dots(config.board, page.shape, BOARD_TEXTURE_DOTS_PER_MM) * m_per_dot
        quad = _textured_quad_obj(work / "board.obj", (page.shape[1] * m_per_dot, page.shape[0] * m_per_dot), 0.0,
                                  page_png)
        pose = np.eye(4)
        pose[:2, 3] = -offset  # the chequered area's centre at the origin
        _add_anchored(scene, Mesh(str(quad)), pose, "board", TABLE_LABEL, None)
    if markers is not None:
        _add_markers(scene, markers, work)
    if config.room:
        _add_room(scene, config, work)
    return scene


class HandheldRenderer:
    """Colour at ``supersample`` times the size (averaged down), depth and labels at the image's size,
    each rendered on the lens's pinhole canvas and seen through its distortion (:class:`LensWarp`)."""

    def __init__(self, scene: RenderScene, cam: CameraIntrinsics, supersample: int, far_m: float):
        from pydrake.geometry import ClippingRange, ColorRenderCamera, DepthRange, DepthRenderCamera, RenderCameraCore
        from pydrake.math import RigidTransform
        from pydrake.systems.sensors import CameraInfo

        k = int(supersample)
        self.lens = LensWarp(cam, cam.k1, cam.k2)
        c = self.lens.canvas

        def core(scale: int):
            # Pixel centres at u + 0.5 on both grids: a k x k block's mean lands on the small pixel's centre.
            info = CameraInfo(c.width * scale, c.height * scale, c.fl_x * scale, c.fl_y * scale, c.cx * scale,
                              c.cy * scale)
            return RenderCameraCore("vtk", info, ClippingRange(0.01, far_m), RigidTransform())

        self.big = ColorRenderCamera(core(k), False)
        self.small = ColorRenderCamera(core(1), False)
        self.depth = DepthRenderCamera(core(1), DepthRange(0.02, 0.9 * far_m))
        self.scene, self.k, self._RigidTransform = scene, k, RigidTransform

    def render(self, c2w_gl: np.ndarray, blur_px: np.ndarray, truth: bool):
        """(RGB uint8, depth m or None, label or None); ``blur_px``: the streak (2,), px of the output."""
        s = self.scene
        query = s.sg.get_query_output_port().Eval(s.sg_context)
        x_wc = self._RigidTransform(c2w_gl @ CV_FROM_GL)
        world = s.sg.world_frame_id()
        big = query.RenderColorImage(self.big, world, x_wc).data[:, :, :3].astype(np.float32)
        big = motion_blur(big, np.asarray(blur_px, dtype=float) * self.k)
        h, w = big.shape[0] // self.k, big.shape[1] // self.k
        rgb = self.lens.apply(big.reshape(h, self.k, w, self.k, 3).mean(axis=(1, 3)))
        rgb = np.clip(np.round(rgb), 0, 255).astype(np.uint8)
        if not truth:
            return rgb, None, None
        # depth along the optical axis belongs to the 3D point, which the lens only moves in the image
        depth = self.lens.apply(query.RenderDepthImage(self.depth, world, x_wc).data[:, :, 0].copy(), nearest=True)
        label = self.lens.apply(query.RenderLabelImage(self.small, world, x_wc).data[:, :, 0].copy(), nearest=True)
        return rgb, depth, label
