"""The evaluation's scenes in Drake: the tasks (planar pushing, the tilting ramp), their settings, where
the object is placed, and the plant they build.
"""
