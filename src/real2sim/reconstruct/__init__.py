"""Reconstruct stage: dataset -> textured mesh in the robot frame (radiance field or visual
hull, TSDF fusion, marching cubes, texture; or an external mesh imported).

Empty until the reconstruction issue lands its modules here.
"""

