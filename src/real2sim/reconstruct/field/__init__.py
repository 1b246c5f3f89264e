"""The voxel radiance field: its grid, training with per-view pose and exposure corrections, surface
extraction (marching cubes or TSDF fusion) and texture.
"""
