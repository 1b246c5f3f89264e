"""`real2sim board`: the printable marker board that gives phone captures metres and the table plane."""

from __future__ import annotations

import argparse
from pathlib import Path

from real2sim.cli import options
from real2sim.cli.options import number

#: --board-square-mm: the printed square side, mm (the page's margins bound it too).
SQUARE_MM = number(2.0, 200.0)


def squares(text: str) -> tuple[int, int]:
    """argparse type of ``--squares``: ``COLSxROWS`` (e.g. 7x5), 2..40 each; the longer side comes first."""
    parts = text.lower().replace("×", "x").split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise argparse.ArgumentTypeError(f"expected COLSxROWS such as 7x5, got {text!r}")
    a, b = sorted((int(parts[0]), int(parts[1])), reverse=True)
    if not (2 <= b and a <= 40):
        raise argparse.ArgumentTypeError(f"expected 2..40 squares a side, got {text!r}")
    return a, b


def register(sub) -> None:
    p = sub.add_parser(
        "board",
        help="write the printable ChArUco board (PDF + PNG) that phone captures lie on",
        description="A ChArUco board (chessboard squares with ArUco markers, OpenCV) as a one-page landscape PDF and "
        "a PNG beside it (same name, .png), both at 609.6 dpi. Print it at 100 % (no 'fit to page'), lay it flat "
        "on the table under the object, and photograph the object standing on it: `run` finds it and sets metres, "
        "the table plane (z = 0) and the world frame (origin at the board's centre, x along its long side). The "
        "square size is printed on the page and stored in the files' metadata.",
        epilog="example: real2sim board --out board.pdf --paper letter",
    )
    p.add_argument("--out", type=Path, required=True, metavar="PDF", help="output PDF path (the PNG goes beside it)")
    p.add_argument("--paper", choices=["a4", "letter"], default="a4", help="paper size, landscape (default a4)")
    p.add_argument("--squares", type=squares, default=None, metavar="COLSxROWS",
                   help="chessboard squares (default 7x5); the longer side is the board's x axis")
    p.add_argument("--board-square-mm", type=SQUARE_MM, default=None, metavar="MM",
                   help="printed square side, mm (default 32 for 7x5; other --squares: the largest whole mm that "
                   "fits the paper); markers are 3/4 of it")
    p.add_argument("--overwrite", action="store_true", help="replace the PDF and PNG if they exist")
    options.finish(p)
    options.declare_paths(p, writes=("out",))
    p.set_defaults(func=run_board)


def run_board(args: argparse.Namespace) -> int:
    from real2sim.capture.phone.board import DEFAULT_BOARD, board_spec_for_paper, write_board
    from real2sim.plumbing.errors import UserInputError
    from real2sim.plumbing.outputs import check_output_path, check_replaceable

    pdf = Path(args.out)
    if pdf.suffix.lower() != ".pdf":
        raise UserInputError(f"--out {pdf}: the board is written as a PDF; name it something.pdf")
    png = pdf.with_suffix(".png")
    for path in (pdf, png):
        check_output_path(path, what="board")
        if path.is_dir():
            raise UserInputError(f"{path} is a folder; --out names the PDF file to write")
        if path.exists() and not args.overwrite:
            raise UserInputError(f"{path} exists (use --overwrite to replace it)")
        check_replaceable(path, what="board")
    cols, rows = args.squares or (DEFAULT_BOARD.squares_x, DEFAULT_BOARD.squares_y)
    spec = board_spec_for_paper(args.paper, cols, rows, None if args.board_square_mm is None else args.board_square_mm / 1000.0)
    made = [folder for folder in (pdf.parent, *pdf.parent.parents) if not folder.exists()]
    pdf.parent.mkdir(parents=True, exist_ok=True)
    try:
        write_board(pdf, png, spec, paper=args.paper)
    except BaseException:
        for folder in made:  # deepest first: only the folders this command made, and only while empty
            try:
                folder.rmdir()
            except OSError:
                break
        raise
    print(f"board: {pdf} and {png} ({spec.describe()}, {args.paper}); print at 100 %, then check that a square "
          f"measures {1000 * spec.square_m:g} mm")
    return 0
