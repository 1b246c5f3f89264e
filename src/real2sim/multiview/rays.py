"""How far along each ray the first surface of a triangle mesh lies, from Embree (``embreex``, the ray
tracer behind trimesh's ray queries).

trimesh's ``intersects_location`` asks Embree for the first face each ray meets and then works out every
hit's position again in Python (a plane-line intersection per hit): on the carving's visibility tests and
the field's ray ranges that second step cost more than Embree's own. Embree returns the distance itself.
Like trimesh, the mesh is moved to its bounding box's corner and scaled to about 100 units first, since
Embree works in float32.
"""

from __future__ import annotations

import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

#: Embree's distance for a ray that meets nothing (1e37); anything beyond this is a miss.
_MISSED = 1e36
#: The scaled mesh's bounding-box diagonal, in Embree's units (trimesh's choice).
_SCALED_DIAGONAL = 100.0


class SurfaceRays:
    """One mesh's Embree scene (built once), for the first hit along many rays."""

    def __init__(self, mesh: trimesh.Trimesh):
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        self.mesh = mesh
        self._corner = vertices.min(axis=0) if len(vertices) else np.zeros(3)
        diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0))) if len(vertices) else 0.0
        self._scale = _SCALED_DIAGONAL / diagonal if diagonal > 0 else 1.0
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self._scene, vertices=((vertices - self._corner) * self._scale).astype(np.float32),
                     indices=np.asarray(mesh.faces, dtype=np.int32))

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(P,) the ray parameter t of each ray's first hit (the point ``origins + t * directions``: metres
        along unit ``directions``), ``inf`` where a ray meets nothing; ``origins`` (P, 3) in the mesh's
        frame and unit, ``directions`` (P, 3)."""
        if len(origins) == 0 or len(self.mesh.faces) == 0:
            return np.full(len(origins), np.inf)
        scaled = ((np.asarray(origins, dtype=np.float64) - self._corner) * self._scale).astype(np.float32)
        t = self._scene.run(scaled, np.asarray(directions, dtype=np.float32), query="DISTANCE").astype(np.float64)
        return np.where(t < _MISSED, t / self._scale, np.inf)
