"""The capture's scene in Drake: the textured table (or a thin stand against a dark background) and
the object under a ring of lights, rendered by the VTK engine (colour, depth along the optical axis,
labels)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from real2sim.formats.dataset import CV_FROM_GL, CameraIntrinsics

OBJECT_LABEL = 1
TABLE_LABEL = 2
STAND_LABEL = 3
#: The room behind a handheld capture's table (capture/sim/room.py): walls, shelves, clutter.
ROOM_LABEL = 4

#: Background of a capture without a table: near black, like the dark drapes of real turntable rigs.
DARK_BACKGROUND = (0.04, 0.04, 0.045)


def _lights():
    from pydrake.geometry import LightParameter
    from pydrake.geometry import Rgba

    lights = []
    # A ring light above the table (as in the paper's rig) + a weak headlight: even, shadow-free light.
    for k in range(8):
        a = 2 * np.pi * k / 8
        lights.append(LightParameter(type="point", frame="world", intensity=0.09,
                                     position=[0.5 * np.cos(a), 0.5 * np.sin(a), 0.9],
                                     color=Rgba(1, 1, 1, 1)))
    # Low fill lights (walls / room light) so that vertical faces are not left dark.
    for k in range(6):
        a = 2 * np.pi * (k + 0.5) / 6
        lights.append(LightParameter(type="point", frame="world", intensity=0.07,
                                     position=[1.2 * np.cos(a), 1.2 * np.sin(a), 0.3],
                                     color=Rgba(1, 1, 1, 1)))
    lights.append(LightParameter(type="directional", frame="camera", intensity=0.3, direction=[0, 0, 1]))
    return lights


class RenderScene:
    """A SceneGraph with the textured table and object, and a VTK renderer.

    ``table_texture`` None: no table; instead ``stand_m`` (radius, length) is a plain grey post
    under the object, its top at z = 0, labelled ``STAND_LABEL``, against a dark background.
    ``far_m``: the far clipping distance (depth is measured to 0.9 of it)."""

    def __init__(self, obj_path: Path, world_from_mesh: np.ndarray, table_texture: Path | None,
                 table_size_m: float, cam: CameraIntrinsics, stand_m: tuple[float, float] | None = None,
                 far_m: float = 10.0):
        from pydrake.geometry import (
            Box,
            ClippingRange,
            ColorRenderCamera,
            Cylinder,
            DepthRange,
            DepthRenderCamera,
            GeometryInstance,
            MakeRenderEngineVtk,
            Mesh,
            PerceptionProperties,
            RenderCameraCore,
            RenderEngineVtkParams,
            SceneGraph,
        )
        from pydrake.geometry import RenderLabel, Rgba
        from pydrake.math import RigidTransform
        from pydrake.systems.framework import DiagramBuilder
        from pydrake.systems.sensors import CameraInfo

        builder = DiagramBuilder()
        self.sg = builder.AddSystem(SceneGraph())
        params = RenderEngineVtkParams()
        params.default_clear_color = [0.25, 0.25, 0.27] if table_texture is not None else list(DARK_BACKGROUND)
        params.lights = _lights()
        self.sg.AddRenderer("vtk", MakeRenderEngineVtk(params))
        self.source = self.sg.RegisterSource("capture")

        if table_texture is not None:
            table_thickness = 0.04
            table = GeometryInstance(RigidTransform([0, 0, -table_thickness / 2]),
                                     Box(table_size_m, table_size_m, table_thickness), "table")
            props = PerceptionProperties()
            props.AddProperty("label", "id", RenderLabel(TABLE_LABEL))
            props.AddProperty("phong", "diffuse_map", str(table_texture))
            table.set_perception_properties(props)
            self.table_id = self.sg.RegisterAnchoredGeometry(self.source, table)
        elif stand_m is not None:
            radius_m, length_m = stand_m
            stand = GeometryInstance(RigidTransform([0, 0, -length_m / 2]), Cylinder(radius_m, length_m), "stand")
            props = PerceptionProperties()
            props.AddProperty("label", "id", RenderLabel(STAND_LABEL))
            props.AddProperty("phong", "diffuse", Rgba(0.35, 0.35, 0.35, 1.0))
            stand.set_perception_properties(props)
            self.sg.RegisterAnchoredGeometry(self.source, stand)

        obj = GeometryInstance(RigidTransform(world_from_mesh), Mesh(str(obj_path)), "object")
        props = PerceptionProperties()
        props.AddProperty("label", "id", RenderLabel(OBJECT_LABEL))
        obj.set_perception_properties(props)
        self.object_id = self.sg.RegisterAnchoredGeometry(self.source, obj)

        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.sg_context = self.sg.GetMyContextFromRoot(self.context)
        info = CameraInfo(cam.width, cam.height, cam.fl_x, cam.fl_y, cam.cx, cam.cy)
        core = RenderCameraCore("vtk", info, ClippingRange(0.01, far_m), RigidTransform())
        self.color_cam = ColorRenderCamera(core, False)
        self.depth_cam = DepthRenderCamera(core, DepthRange(0.02, 0.9 * far_m))
        self._RigidTransform = RigidTransform

    def remove_object(self) -> None:
        from pydrake.geometry import Role

        self.sg.RemoveRole(self.sg_context, self.source, self.object_id, Role.kPerception)

    def render(self, c2w_gl: np.ndarray, depth: bool = True, label: bool = True):
        """RGB uint8 (H,W,3), depth float32 metres (inf = none), label int (H,W) for one OpenGL c2w pose."""
        query = self.sg.get_query_output_port().Eval(self.sg_context)
        x_wc = self._RigidTransform(c2w_gl @ CV_FROM_GL)  # Drake cameras look along +z, y down
        world = self.sg.world_frame_id()
        rgb = query.RenderColorImage(self.color_cam, world, x_wc).data[:, :, :3].copy()
        d = query.RenderDepthImage(self.depth_cam, world, x_wc).data[:, :, 0].copy() if depth else None
        lab = query.RenderLabelImage(self.color_cam, world, x_wc).data[:, :, 0].copy() if label else None
        return rgb, d, lab
