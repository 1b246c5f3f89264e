"""A mesh's silhouette from its projected faces (real2sim.geometry.silhouettes.filled_triangles), and the masks
from geometry drawn with it (real2sim.multiview.solid.solid_masks)."""

import cv2
import numpy as np

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.geometry.silhouettes import filled_triangles
from real2sim.multiview.solid import ObjectSolid, solid_masks
from real2sim.multiview.voxel_grid import VoxelGrid


def test_overlapping_triangles_fill_their_union():
    # two triangles overlapping in [10, 20]^2: OpenCV's one-call polygon fill leaves that overlap empty
    a = [[5.0, 5.0], [30.0, 5.0], [5.0, 30.0]]
    b = [[10.0, 10.0], [35.0, 10.0], [10.0, 35.0]]
    both = filled_triangles(40, 40, np.array([a, b]))
    alone = filled_triangles(40, 40, np.array([a])) | filled_triangles(40, 40, np.array([b]))
    assert both[12, 12] == 1 and np.array_equal(both, alone)
    assert filled_triangles(40, 40, np.array([a, a])).sum() == filled_triangles(40, 40, np.array([a])).sum()


def test_a_pixel_is_drawn_where_the_triangles_cover_its_centre():
    square = np.array([[[2.0, 2.0], [6.0, 2.0], [6.0, 6.0]], [[2.0, 2.0], [6.0, 6.0], [2.0, 6.0]]])
    drawn = filled_triangles(10, 10, square)
    assert drawn[2:6, 2:6].all() and drawn.sum() <= 4 * 4 + 2 * 4 + 1  # the square, its edge pixels at most
    far = np.array([[[1e9, 1e9], [2e9, 1e9], [1e9, 2e9]], [[-50.0, -50.0], [-40.0, -50.0], [-50.0, -40.0]]])
    assert filled_triangles(10, 10, far).sum() == 0  # off the picture: nothing, and no overflow


def test_a_solid_s_mask_has_no_holes_where_its_surfaces_overlap():
    # a solid block seen from above at an angle: its near and far faces overlap in the picture
    grid = VoxelGrid.covering(np.array([-0.05, -0.05, 0.0]), np.array([0.05, 0.05, 0.1]), 20, table_z_m=0.0)
    occupied = np.zeros(grid.shape, bool)
    occupied[4:-4, 4:-4, :-4] = True
    solid = ObjectSolid(grid, occupied, np.eye(4))
    k = CameraIntrinsics(fl_x=200.0, fl_y=200.0, cx=80.0, cy=60.0, width=160, height=120)
    eye, target = np.array([0.25, 0.1, 0.3]), np.array([0.0, 0.0, 0.04])
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([right, np.cross(forward, right), forward], axis=1)  # OpenCV axes: x right, y down
    c2w[:3, 3] = eye
    mask = solid_masks(solid, k, c2w[None])[0] > 0.5
    filled = mask.astype(np.uint8).copy()
    flood = np.zeros((k.height + 2, k.width + 2), np.uint8)
    cv2.floodFill(filled, flood, (0, 0), 1)
    assert mask.sum() > 500 and (filled == 0).sum() == 0  # every pixel not reached from outside is in the mask
