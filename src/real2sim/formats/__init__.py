"""The on-disk contracts between stages: dataset, collision SPEC, collision geometry,
physical properties, contact material, results CSVs, trajectories, joint logs (atomic outputs and
user errors are :mod:`real2sim.plumbing`'s, mesh I/O :mod:`real2sim.geometry.mesh_io`'s).

Importable without torch or Drake (an import-linter contract keeps it so): every
stage reads and writes its files through these modules, never through another
stage's internals.
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "CollisionSpec": "spec",
    "parse_spec": "spec",
    "CollisionGeometry": "collision",
    "CollisionShape": "collision",
    "read_collision_json": "collision",
    "write_collision_json": "collision",
    "PhysicalProperties": "physical",
    "read_physical_properties": "physical",
    "write_physical_properties": "physical",
    "ContactProperties": "contact",
    "Dataset": "dataset",
    "Frame": "dataset",
    "read_dataset": "dataset",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
