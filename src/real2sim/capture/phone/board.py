"""The printed marker board: a ChArUco board (OpenCV ``aruco``) that gives phone captures metres,
the table plane and a world frame.

Board frame (what :class:`BoardView` and :mod:`.board_frame` use): metres, the origin at the centre
of the chequered area, x along its long side (``squares_x``, to the right on the printed page),
y towards the top of the printed page, z up out of the paper. Lying on the table it is the world
frame of a phone capture: the table top is z = 0.

Pixels follow the project's convention (:class:`~real2sim.formats.dataset.CameraIntrinsics`,
COLMAP's too): the centre of pixel (u, v) is at (u + 0.5, v + 0.5). OpenCV puts it at (u, v);
:func:`detect_board` shifts its corners by half a pixel before solving for the pose.

The page (:func:`write_board`) is drawn at a whole number of dots per millimetre so that every
square has the same size in dots; the PDF and the PNG say their resolution, so printed at 100 %
(no "fit to page") the squares are ``square_m`` wide. The square size is printed on the page and
stored in both files' metadata (:func:`read_board_spec`).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from real2sim.plumbing.errors import UserInputError

#: Paper sizes, landscape (width, height), millimetres.
PAPER_MM = {"a4": (297.0, 210.0), "letter": (279.4, 215.9)}
#: White border kept clear around the chequered area, mm: printers do not print to the edge, and
#: ArUco detection needs a quiet zone around the outer markers.
PAGE_MARGIN_MM = 12.0
#: Height of the text line under the board, mm.
TEXT_BAND_MM = 9.0
#: Drawing resolution of the page: 24 dots per mm (609.6 dpi), whole dots per mm.
DOTS_PER_MM = 24
#: Marker side as a fraction of the square side (OpenCV's examples use 0.7-0.8).
MARKER_FRACTION = 0.75
#: Metadata key of the board's description in the PNG text chunk and the PDF's keywords.
METADATA_KEY = "real2sim_board"
#: Fewest ChArUco corners for a pose: fewer is too easily a wrong or ill-conditioned PnP solution.
MIN_CORNERS = 6
#: A corner further than this from where the others put it (or 3x their median, px) is left out.
OUTLIER_CORNER_PX = 1.0
#: A pose whose corners reproject worse than this (RMS, px) is not a detection of this board.
MAX_REPROJECTION_PX = 3.0


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: ``squares_x`` x ``squares_y`` chessboard squares of ``square_m`` (metres),
    ArUco markers of ``marker_m`` from OpenCV's predefined ``dictionary`` (its name, e.g.
    ``"DICT_4X4_50"``) in the white squares. ``squares_x >= squares_y``: x is the long side. ``source``: the
    file it was read from (:func:`read_board_spec`), for messages only: not part of the layout, its
    equality or its JSON."""

    squares_x: int = 7
    squares_y: int = 5
    square_m: float = 0.032
    marker_m: float = 0.024
    dictionary: str = "DICT_4X4_50"
    source: str | None = field(default=None, compare=False, repr=False)

    def validate(self) -> None:
        if not (2 <= self.squares_y <= self.squares_x <= 40):
            raise UserInputError(f"board squares {self.squares_x}x{self.squares_y}: need 2..40 squares a side, "
                                 "the longer side first (e.g. 7x5)")
        if not (np.isfinite(self.square_m) and 0.002 <= self.square_m <= 1.0):
            raise UserInputError(f"board square {1000 * self.square_m:g} mm: out of range (2..1000 mm)")
        if not (np.isfinite(self.marker_m) and 0 < self.marker_m < self.square_m):
            raise UserInputError(f"board marker {1000 * self.marker_m:g} mm must be smaller than its square "
                                 f"({1000 * self.square_m:g} mm)")
        import cv2

        if not self.dictionary.startswith("DICT_") or not hasattr(cv2.aruco, self.dictionary):
            raise UserInputError(f"unknown ArUco dictionary {self.dictionary!r} (e.g. DICT_4X4_50)")
        markers = (self.squares_x * self.squares_y) // 2
        size = int(self.dictionary.rsplit("_", 1)[-1]) if self.dictionary.rsplit("_", 1)[-1].isdigit() else 1 << 30
        if markers > size:
            raise UserInputError(f"a {self.squares_x}x{self.squares_y} board needs {markers} markers; "
                                 f"{self.dictionary} has {size}")

    @property
    def size_m(self) -> tuple[float, float]:
        """(long, short) side of the chequered area, metres."""
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    def with_square_m(self, square_m: float) -> "BoardSpec":
        """The same board printed at another scale (``--board-square-mm``): markers keep their ratio."""
        return BoardSpec(self.squares_x, self.squares_y, float(square_m), float(square_m) * self.marker_m / self.square_m,
                         self.dictionary, self.source)

    def to_json(self) -> dict:
        return {k: v for k, v in asdict(self).items() if k != "source"}

    @staticmethod
    def from_json(data: dict) -> "BoardSpec":
        try:
            spec = BoardSpec(int(data["squares_x"]), int(data["squares_y"]), float(data["square_m"]),
                             float(data["marker_m"]), str(data["dictionary"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise UserInputError(f"not a board description ({type(exc).__name__}: {exc})") from None
        spec.validate()
        return spec

    def describe(self) -> str:
        return (f"{self.squares_x}x{self.squares_y} ChArUco board, squares {1000 * self.square_m:g} mm, "
                f"markers {1000 * self.marker_m:g} mm, {self.dictionary}")

    def label(self) -> str:
        """How a message names the board: its layout and, when it was read from one, its file."""
        layout = f"{self.squares_x}x{self.squares_y}, {1000 * self.square_m:g} mm squares"
        return layout + (f", from {self.source}" if self.source else "")


#: The board `real2sim board` prints by default, on A4 and on US letter alike (same squares).
DEFAULT_BOARD = BoardSpec()


def board_spec_for_paper(paper: str, squares_x: int, squares_y: int, square_m: float | None = None) -> BoardSpec:
    """The board of ``squares_x`` x ``squares_y`` squares for ``paper``: ``square_m`` when given
    (UserInputError later if it does not fit), else the default's square (32 mm) when it fits, else
    the largest whole millimetre that does. Markers are ``MARKER_FRACTION`` of the square."""
    if paper not in PAPER_MM:
        raise UserInputError(f"unknown paper {paper!r} (a4 or letter)")
    squares_x, squares_y = max(squares_x, squares_y), min(squares_x, squares_y)
    if square_m is None:
        w_mm, h_mm = PAPER_MM[paper]
        fit_mm = min((w_mm - 2 * PAGE_MARGIN_MM) / squares_x, (h_mm - 2 * PAGE_MARGIN_MM - TEXT_BAND_MM) / squares_y)
        square_m = min(1000 * DEFAULT_BOARD.square_m, float(np.floor(fit_mm))) / 1000.0
        if square_m < 0.002:
            raise UserInputError(f"{squares_x}x{squares_y} squares do not fit {paper} paper: use fewer")
    spec = BoardSpec(squares_x, squares_y, float(square_m), round(MARKER_FRACTION * float(square_m), 6),
                     DEFAULT_BOARD.dictionary if squares_x * squares_y // 2 <= 50 else "DICT_4X4_250")
    spec.validate()
    return spec


@dataclass(frozen=True)
class BoardView:
    """The board seen in one image.

    ``camera_from_board``: 4x4 rigid transform, metres, from the board frame (module docstring) to
    the camera's OpenCV axes (x right, y down, z forward). ``corner_count``: ChArUco corners used;
    ``reprojection_px``: their RMS reprojection error. ``image_points_px`` (N, 2, project pixel
    convention), ``board_points_m`` (N, 3, board frame), ``K``, ``dist``: what the pose was solved
    from, kept for joint refinement (:mod:`.board_frame`)."""

    camera_from_board: np.ndarray
    corner_count: int
    reprojection_px: float
    image_points_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), compare=False, repr=False)
    board_points_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), compare=False, repr=False)
    K: np.ndarray = field(default_factory=lambda: np.eye(3), compare=False, repr=False)
    dist: np.ndarray = field(default_factory=lambda: np.zeros(4), compare=False, repr=False)


# ----------------------------------------------------------------------------- OpenCV board


def _cv_board(spec: BoardSpec):
    import cv2

    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
    return cv2.aruco.CharucoBoard((spec.squares_x, spec.squares_y), spec.square_m, spec.marker_m, dictionary)


def board_from_opencv(spec: BoardSpec) -> np.ndarray:
    """4x4 from OpenCV's board coordinates (origin at the page's top-left board corner, x right,
    y down the page, z into the paper) to the board frame (centre, y up the page, z out of it)."""
    w, h = spec.size_m
    t = np.diag([1.0, -1.0, -1.0, 1.0])
    t[:3, 3] = [-w / 2, h / 2, 0.0]
    return t


def board_corners_m(spec: BoardSpec) -> np.ndarray:
    """(N, 3) ChArUco (inner chessboard) corners in the board frame, indexed by OpenCV's corner id."""
    pts = np.asarray(_cv_board(spec).getChessboardCorners(), dtype=float)
    t = board_from_opencv(spec)
    return pts @ t[:3, :3].T + t[:3, 3]


def board_image(spec: BoardSpec, dots_per_m: float) -> np.ndarray:
    """The chequered area alone, uint8 greyscale, ``dots_per_m`` dots per metre (a whole number of
    dots per square), the page's top row first."""
    sq = int(round(spec.square_m * dots_per_m))
    return _cv_board(spec).generateImage((spec.squares_x * sq, spec.squares_y * sq), marginSize=0, borderBits=1)


# ----------------------------------------------------------------------------- the printed page


def board_centre_on_page_dots(spec: BoardSpec, page_shape: tuple[int, int], dots_per_mm: int) -> np.ndarray:
    """(x, y) of the chequered area's centre from the page's centre, in dots (x right, y up the
    page), as :func:`page_image` lays out a page of ``page_shape`` (rows, columns)."""
    sq = int(round(spec.square_m * 1000.0 * dots_per_mm))
    board_h, board_w = sq * spec.squares_y, sq * spec.squares_x
    top = int(round((page_shape[0] - TEXT_BAND_MM * dots_per_mm - board_h) / 2))
    left = (page_shape[1] - board_w) // 2
    return np.array([left + board_w / 2 - page_shape[1] / 2, page_shape[0] / 2 - (top + board_h / 2)])


def page_image(spec: BoardSpec, paper: str = "a4", dots_per_mm: int = DOTS_PER_MM) -> np.ndarray:
    """The whole landscape page, uint8 greyscale: the board centred above a line of text that says
    what it is and how to print it. UserInputError when the board does not fit the paper."""
    from PIL import Image, ImageDraw, ImageFont

    spec.validate()
    if paper not in PAPER_MM:
        raise UserInputError(f"unknown paper {paper!r} (a4 or letter)")
    page_w_mm, page_h_mm = PAPER_MM[paper]
    board_w_mm, board_h_mm = 1000 * spec.size_m[0], 1000 * spec.size_m[1]
    if board_w_mm > page_w_mm - 2 * PAGE_MARGIN_MM or board_h_mm > page_h_mm - 2 * PAGE_MARGIN_MM - TEXT_BAND_MM:
        raise UserInputError(f"a {board_w_mm:g} x {board_h_mm:g} mm board does not fit {paper} paper with "
                             f"{PAGE_MARGIN_MM:g} mm margins: use fewer or smaller squares")
    page = np.full((int(round(page_h_mm * dots_per_mm)), int(round(page_w_mm * dots_per_mm))), 255, np.uint8)
    board = board_image(spec, 1000.0 * dots_per_mm)
    top = int(round((page.shape[0] - TEXT_BAND_MM * dots_per_mm - board.shape[0]) / 2))
    left = (page.shape[1] - board.shape[1]) // 2
    page[top:top + board.shape[0], left:left + board.shape[1]] = board
    img = Image.fromarray(page)
    draw = ImageDraw.Draw(img)
    text = (f"real2sim board: {spec.squares_x}x{spec.squares_y} squares of {1000 * spec.square_m:g} mm, markers "
            f"{1000 * spec.marker_m:g} mm, {spec.dictionary}. Print at 100 % (no fit to page); if a square does "
            f"measure {1000 * spec.square_m:g} mm, give run --board-square-mm.")
    font_px = int(3.2 * dots_per_mm)
    try:
        font = ImageFont.load_default(size=font_px)
    except TypeError:  # Pillow without FreeType: the small bitmap font, still legible when printed
        font = ImageFont.load_default()
    y = top + board.shape[0] + int(0.35 * TEXT_BAND_MM * dots_per_mm)
    width = draw.textlength(text, font=font)
    draw.text((max((page.shape[1] - width) / 2, PAGE_MARGIN_MM * dots_per_mm), y), text, fill=0, font=font)
    return np.asarray(img)


def write_board(pdf_path: Path | str, png_path: Path | str, spec: BoardSpec = DEFAULT_BOARD, paper: str = "a4") -> None:
    """Write the printable page as a one-page PDF and a PNG (both at ``DOTS_PER_MM``, stated in the
    files so that they print at true size); the board's description (:meth:`BoardSpec.to_json`) is
    in the PDF's keywords and the PNG's text chunk ``real2sim_board``. Each file appears whole or
    not at all."""
    from PIL import Image, PngImagePlugin

    from real2sim.plumbing.outputs import atomic_file

    page = Image.fromarray(page_image(spec, paper)).convert("1")  # black and white: crisp, small, lossless
    dpi = DOTS_PER_MM * 25.4
    description = json.dumps({**spec.to_json(), "paper": paper})
    info = PngImagePlugin.PngInfo()
    info.add_text(METADATA_KEY, description)
    info.add_text("Description", spec.describe())
    # Both written before either is renamed into place: a failure leaves neither.
    with atomic_file(Path(png_path)) as png_tmp, atomic_file(Path(pdf_path)) as pdf_tmp:
        page.save(png_tmp, format="PNG", dpi=(dpi, dpi), pnginfo=info)
        page.save(pdf_tmp, format="PDF", resolution=dpi, title=f"real2sim board ({spec.describe()})",
                  subject=spec.describe(), keywords=f"{METADATA_KEY}={description}", creator="real2sim board")


def read_board_spec(path: Path | str) -> BoardSpec:
    """The board described in a PNG or PDF that :func:`write_board` wrote (UserInputError otherwise)."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".pdf":
            from PIL import PdfParser

            try:
                text = PdfParser.PdfParser(str(path)).info.Keywords
            except (AttributeError, KeyError, PdfParser.PdfFormatError, IndexError, ValueError):
                text = None
        else:
            from PIL import Image, UnidentifiedImageError

            try:
                with Image.open(path) as img:
                    text = getattr(img, "text", {}).get(METADATA_KEY)
            except UnidentifiedImageError:
                text = None
            text = f"{METADATA_KEY}={text}" if text else None
    except OSError as exc:
        raise UserInputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not text or not text.startswith(f"{METADATA_KEY}="):
        raise UserInputError(f"{path}: not a board written by `real2sim board` (no {METADATA_KEY} metadata)")
    try:
        data = json.loads(text[len(METADATA_KEY) + 1:])
    except json.JSONDecodeError:
        raise UserInputError(f"{path}: its {METADATA_KEY} metadata is not JSON") from None
    return replace(BoardSpec.from_json(data), source=str(path))


# ----------------------------------------------------------------------------- detection


def opencv_camera_matrix(K: np.ndarray) -> np.ndarray:
    """A copy of the camera matrix ``K`` (3x3, the project's pixel convention: a pixel's centre at u + 0.5)
    in OpenCV's (the centre at u): the principal point half a pixel lower. Image points convert the same
    way (minus 0.5)."""
    K_cv = np.array(K, dtype=float)
    K_cv[:2, 2] -= 0.5
    return K_cv


def detect_board(image_rgb: np.ndarray, spec: BoardSpec, K: np.ndarray, dist=None) -> BoardView | None:
    """The board's pose in one image, or None when it is not found well enough.

    ``image_rgb``: (H, W, 3) uint8 (or (H, W) greyscale). ``K``: 3x3 intrinsics with pixel centres
    at u + 0.5 (module docstring); ``dist``: OpenCV (k1, k2, p1, p2) or None for none. The ChArUco
    corners (at least ``MIN_CORNERS``, refined to sub-pixel accuracy by OpenCV) give the pose by
    planar PnP (IPPE) refined by Levenberg-Marquardt; a pose whose RMS reprojection error exceeds
    ``MAX_REPROJECTION_PX`` is refused (a wrong marker identity or a bad corner)."""
    import cv2

    img = np.asarray(image_rgb)
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    grey = np.ascontiguousarray(grey, dtype=np.uint8)
    K = np.asarray(K, dtype=float)
    dist_cv = np.zeros(4) if dist is None else np.asarray(dist, dtype=float).ravel()
    K_cv = opencv_camera_matrix(K)
    board = _cv_board(spec)
    params = cv2.aruco.CharucoParameters()
    params.cameraMatrix, params.distCoeffs = K_cv, dist_cv
    # A corner next to one found marker is kept (OpenCV's default wants two): the object hides the
    # board's middle, and at phone resolutions far markers drop out; the corner's sub-pixel fit and
    # the reprojection check below catch a wrong one. Markers missed at first are looked for again
    # where the board says they must be.
    params.minMarkers, params.tryRefineMarkers = 1, True
    detector_params = cv2.aruco.DetectorParameters()
    detector_params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX  # markers' corners, for the corner fit
    detector = cv2.aruco.CharucoDetector(board, params, detector_params)
    corners, ids, _, _ = detector.detectBoard(grey)
    if ids is None:
        return None
    return board_view_from_corners(ids.ravel(), corners.reshape(-1, 2) + 0.5, spec, K, dist_cv)


def board_view_from_corners(ids: np.ndarray, corners_px: np.ndarray, spec: BoardSpec, K: np.ndarray,
                            dist=None) -> BoardView | None:
    """The board's pose from found ChArUco corners: ``ids`` (N,) OpenCV corner ids, ``corners_px``
    (N, 2) in the project's pixel convention (centres at u + 0.5). None when they are too few, on
    one line, or reproject worse than ``MAX_REPROJECTION_PX`` after the fit."""
    import cv2

    ids = np.asarray(ids).ravel().astype(int)
    if len(ids) < MIN_CORNERS:
        return None
    K = np.asarray(K, dtype=float)
    dist_cv = np.zeros(4) if dist is None else np.asarray(dist, dtype=float).ravel()
    K_cv = opencv_camera_matrix(K)
    image_px = np.asarray(corners_px, dtype=float).reshape(-1, 2) - 0.5  # OpenCV's pixel centres
    board_pts = board_corners_m(spec)[ids]
    # Corners along one line leave the pose undetermined.
    if np.linalg.matrix_rank(board_pts[:, :2] - board_pts[:, :2].mean(0), tol=1e-3 * spec.square_m) < 2:
        return None
    keep = np.ones(len(ids), dtype=bool)
    for _ in range(3):
        ok, rvec, tvec = cv2.solvePnP(board_pts[keep], image_px[keep], K_cv, dist_cv, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            return None
        rvec, tvec = cv2.solvePnPRefineLM(board_pts[keep], image_px[keep], K_cv, dist_cv, rvec, tvec)
        proj, _ = cv2.projectPoints(board_pts, rvec, tvec, K_cv, dist_cv)
        err = np.linalg.norm(proj.reshape(-1, 2) - image_px, axis=1)
        # A corner the object hides is still "found" next to its visible marker, snapped onto the object's
        # edge: it disagrees with the others by pixels. Leave such corners out and solve again.
        now = err <= max(OUTLIER_CORNER_PX, 3.0 * float(np.median(err[keep])))
        if (now == keep).all() or now.sum() < MIN_CORNERS:
            break
        keep = now
    if keep.sum() < MIN_CORNERS:
        return None
    rms = float(np.sqrt(np.mean(err[keep] ** 2)))
    if not np.isfinite(rms) or rms > MAX_REPROJECTION_PX:
        return None
    ids, image_px, board_pts = ids[keep], image_px[keep], board_pts[keep]
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel()
    if T[2, 3] <= 0:  # the board behind the camera: not a real solution
        return None
    return BoardView(camera_from_board=T, corner_count=int(len(ids)), reprojection_px=rms,
                     image_points_px=image_px + 0.5, board_points_m=board_pts, K=K, dist=dist_cv)
