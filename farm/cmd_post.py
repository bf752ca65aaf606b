"""``nephele post``: contact sheet, EXR → PNG, stereo pairs and movies from rendered frames."""

from pathlib import Path

from ..core.camera.anaglyph import MODES as ANAGLYPH_MODES
from ..core.errors import DataError, UsageError

HELP = "post-process frames: contact-sheet, exr2png, stereo (side-by-side, anaglyph), movie (H.264 MP4)"


def frames_of(inputs, eye=None):
    """Image files from files and directories (a directory gives its frame_* files in name order).

    A directory of a stereo render (``frame_NNNN_L`` / ``frame_NNNN_R``) gives
    the frames of one ``eye`` (``"L"`` or ``"R"``); without ``eye`` it is a
    :class:`DataError` rather than a sequence that alternates between the eyes.
    """
    paths = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.name.startswith("frame_")
                           and q.suffix.lower() in (".png", ".exr"))
            if not found:
                raise DataError("no frame_*.png or frame_*.exr files in this directory", path=p)
            stereo = {q.stem[-2:] for q in found} == {"_L", "_R"}
            if eye is not None:
                found = [q for q in found if q.stem.endswith(f"_{eye}")]
                if not found:
                    raise DataError(f"no frame_*_{eye} files in this directory", path=p)
            elif stereo:
                raise DataError("stereo frames (frame_*_L / frame_*_R) in this directory: choose --eye L or R",
                                path=p)
            paths += found
        elif p.is_file():
            paths.append(p)
        else:
            raise DataError("no such file or directory", path=p)
    return paths


def stereo_pairs(directory):
    """``[(left, right)]`` of a farm stereo directory: ``frame_NNNN_L.*`` with ``frame_NNNN_R.*``.

    Raises
    ------
    DataError
        No left-eye frames, or a left frame without its right one (or the reverse).
    """
    d = Path(directory)
    eyes = {"_L": {}, "_R": {}}
    for q in d.iterdir():
        if q.name.startswith("frame_") and q.suffix.lower() in (".png", ".exr") and q.stem[-2:] in eyes:
            eyes[q.stem[-2:]][q.stem[:-2]] = q
    left, right = eyes["_L"], eyes["_R"]
    if not left:
        raise DataError("no stereo frames (frame_*_L.png / frame_*_R.png) in this directory", path=d)
    lone = sorted(set(left) ^ set(right))
    if lone:
        raise DataError(f"frames without both eyes: {', '.join(lone[:5])}{' ...' if len(lone) > 5 else ''}", path=d)
    return [(left[k], right[k]) for k in sorted(left)]


def add_arguments(p):
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    s = sub.add_parser("contact-sheet", help="tile frames into one PNG")
    s.add_argument("inputs", nargs="+", help="frame files or directories")
    s.add_argument("--out", required=True, help="output PNG")
    s.add_argument("--columns", type=int, help="thumbnails per row (default: square-ish)")
    s.add_argument("--thumb-width", type=int, help="thumbnail width in pixels (default: frame width, <= 256)")
    s.add_argument("--every", type=int, default=1, help="take every N-th frame")
    s.add_argument("--view", default="Standard", help="OCIO view for EXR frames (Standard, AgX, ...)")
    s.add_argument("--eye", choices=("L", "R"), help="one eye of a stereo render's directory")
    e = sub.add_parser("exr2png", help="convert EXR frames to 8-bit sRGB PNG")
    e.add_argument("inputs", nargs="+", help="EXR files or directories")
    e.add_argument("--out", required=True, help="output directory")
    e.add_argument("--view", default="Standard", help="OCIO view (Standard = sRGB transfer; AgX = Blender's default)")
    st = sub.add_parser("stereo", help="left/right views → side-by-side and red-cyan anaglyph")
    st.add_argument("left", help="left-eye frame or directory; alone: a stereo render's directory (frame_*_L/_R)")
    st.add_argument("right", nargs="?", help="right-eye frame or directory")
    st.add_argument("--out", required=True, help="output directory (sbs_*.png, anaglyph_*.png)")
    st.add_argument("--anaglyph-mode", choices=ANAGLYPH_MODES, default="colour",
                    help="red from the left eye's colour or grey, green/blue from the right's colour or grey "
                         "(half or grey when saturated red/blue objects must reach both eyes)")
    m = sub.add_parser("movie", help="encode frames as H.264 MP4 (bundled ffmpeg)")
    m.add_argument("inputs", nargs="+", help="frame files or directories")
    m.add_argument("--out", required=True, help="output .mp4")
    m.add_argument("--fps", type=float, default=24.0)
    m.add_argument("--crf", type=int, default=18, help="x264 quality (lower = better, 18 ~ visually lossless)")
    m.add_argument("--view", default="Standard", help="OCIO view for EXR frames")
    m.add_argument("--eye", choices=("L", "R"), help="one eye of a stereo render's directory")


def run(args):
    from . import post

    if args.action == "contact-sheet":
        if args.every < 1:
            raise UsageError(f"--every must be >= 1, got {args.every}")
        paths = frames_of(args.inputs, args.eye)[:: args.every]
        out = post.contact_sheet(paths, args.out, columns=args.columns, thumb_width=args.thumb_width, view=args.view)
        print(f"contact sheet of {len(paths)} frames: {out}")
    elif args.action == "exr2png":
        out_dir = Path(args.out)
        paths = [p for p in frames_of(args.inputs) if p.suffix.lower() == ".exr"]
        if not paths:
            raise DataError("no EXR files among the inputs")
        for p in paths:
            post.exr_to_png(p, out_dir / (p.stem + ".png"), view=args.view)
        print(f"{len(paths)} PNG files in {out_dir}")
    elif args.action == "stereo":
        if args.right is None:
            if not Path(args.left).is_dir():
                raise UsageError("stereo: give LEFT RIGHT, or one directory of frame_*_L / frame_*_R files")
            pairs = stereo_pairs(args.left)
            names = [a.stem[:-2] for a, _ in pairs]  # frame_0001_L -> frame_0001
        else:
            left, right = frames_of([args.left]), frames_of([args.right])
            if len(left) != len(right):
                raise DataError(f"{len(left)} left frames but {len(right)} right frames", path=args.right)
            pairs, names = list(zip(left, right)), [a.stem for a in left]
        out_dir = Path(args.out)
        for (a, b), stem in zip(pairs, names):
            post.side_by_side(a, b, out_dir / f"sbs_{stem}.png")
            post.anaglyph(a, b, out_dir / f"anaglyph_{stem}.png", args.anaglyph_mode)
        print(f"{len(pairs)} side-by-side and anaglyph frames in {out_dir}")
    else:
        paths = frames_of(args.inputs, args.eye)
        out = post.movie(paths, args.out, fps=args.fps, crf=args.crf, view=args.view)
        print(f"movie of {len(paths)} frames at {args.fps:g} fps: {out}")
    return 0
