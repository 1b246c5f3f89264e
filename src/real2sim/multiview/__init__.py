"""Multi-view machinery below the stages: posed views (images, masks, cameras), voxel grids, the visual hull
and sRGB colour, shared by capture's masks and phone normalisation and by reconstruction.
"""
