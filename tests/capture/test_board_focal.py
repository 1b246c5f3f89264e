"""The focal length measured on the printed board (real2sim.capture.phone.board_focal), on board corners
projected through a known camera: the board's corners (DEFAULT_BOARD) seen from an orbit of tilted
views, 0.1 px of corner noise, a lens with a little barrel distortion."""

from __future__ import annotations

import numpy as np
import pytest

from real2sim.capture.phone.board import DEFAULT_BOARD, BoardView
from real2sim.capture.phone.board_focal import MAX_SPLIT_DISAGREEMENT, MIN_VIEWS, focal_from_board

SIZE = (640, 480)
TRUE_F = 500.0
DIST = np.array([-0.05, 0.01, 0.0, 0.0])


def _board_points() -> np.ndarray:
    """The board's inner chessboard corners, board frame (m), z = 0."""
    nx, ny, s = DEFAULT_BOARD.squares_x - 1, DEFAULT_BOARD.squares_y - 1, DEFAULT_BOARD.square_m
    u, v = np.meshgrid((np.arange(nx) - (nx - 1) / 2) * s, (np.arange(ny) - (ny - 1) / 2) * s)
    return np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], axis=1)


def _views(count: int, focal_px, rng) -> list[BoardView]:
    """Views on an orbit at 25-70 degrees elevation looking at the board's centre; ``focal_px`` per view
    (a number, or a function of the view's index)."""
    import cv2

    points = _board_points()
    views = []
    for i in range(count):
        az, el = 2 * np.pi * i / count, np.radians(25 + 45 * (i % 4) / 3)
        centre = 0.25 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        forward = -centre / np.linalg.norm(centre)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        r_cw = np.stack([right, down, forward])  # rows: camera axes in the board frame
        f = focal_px(i) if callable(focal_px) else focal_px
        K_cv = np.array([[f, 0, SIZE[0] / 2 - 0.5], [0, f, SIZE[1] / 2 - 0.5], [0, 0, 1.0]])
        rvec, _ = cv2.Rodrigues(r_cw)
        uv, _ = cv2.projectPoints(points, rvec, -r_cw @ centre, K_cv, DIST)
        uv = uv.reshape(-1, 2) + 0.5 + rng.normal(0, 0.1, (len(points), 2))  # project pixel convention
        views.append(BoardView(np.eye(4), len(points), 0.1, image_points_px=uv, board_points_m=points))
    return views


def _guess(f: float) -> np.ndarray:
    return np.array([[f, 0, SIZE[0] / 2], [0, f, SIZE[1] / 2], [0, 0, 1.0]])


@pytest.mark.parametrize("guess_f", [490.0, 515.0])
def test_the_board_measures_the_focal_length_from_a_wrong_guess(guess_f):
    rng = np.random.default_rng(0)
    views = _views(24, TRUE_F, rng) + [None, None]  # views without the board are skipped
    # SfM's guess of the lens without its barrel distortion: the board measures that too (held, the
    # focal length would be pulled off by it)
    result = focal_from_board(views, _guess(guess_f), np.zeros(4), SIZE)
    assert result.focal_px == pytest.approx(TRUE_F, rel=2e-3), result
    assert result.k1 == pytest.approx(DIST[0], abs=0.01)
    assert result.views == 24 and result.sfm_focal_px == guess_f and result.rms_px < 0.2
    record = result.to_json()
    assert record["change_pct"] == pytest.approx(100 * (result.focal_px / guess_f - 1)) and "not_used" not in record


def test_too_few_views_or_views_that_disagree_are_not_used():
    rng = np.random.default_rng(1)
    few = focal_from_board(_views(MIN_VIEWS - 1, TRUE_F, rng), _guess(505.0), DIST, SIZE)
    assert few.focal_px is None and f"found in {MIN_VIEWS - 1} views" in few.reason
    assert few.to_json()["not_used"] == few.reason
    # every other view through a lens 4 % longer: the two halves cannot agree
    mixed = focal_from_board(_views(24, lambda i: TRUE_F * (1.04 if i % 2 else 1.0), rng), _guess(505.0), DIST, SIZE)
    assert mixed.focal_px is None and mixed.split_disagreement > MAX_SPLIT_DISAGREEMENT
    assert "disagree" in mixed.reason
