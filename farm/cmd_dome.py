"""``nephele dome``: remap cube faces or equirect images to domemaster / Omnimax frames.

Cube faces are found by a pattern with ``{face}`` (one of front, right, back,
left, up, down; see :data:`nephele.core.camera.dome.CUBE_AXES` for their axes), or a
folder holding ``face_<name>.png`` (what the EEVEE cube route keeps).  With
``--frames A-B`` the input and output patterns take ``{frame}`` (e.g.
``{frame:04d}``); the lookup table is built once and reused for every frame.
"""

from pathlib import Path

import numpy as np

from ..core.errors import UsageError
from ..core.parse import parse_range, parse_size

HELP = "remap cube faces or an equirect image to a domemaster or Omnimax frame (antialiased)"


def add_arguments(p):
    p.add_argument("source", help="cube faces: a pattern with {face} or a folder of face_<name>.png; "
                                   "equirect: an image file (pattern with {frame} for sequences)")
    p.add_argument("--out", required=True, help="output image (pattern with {frame} for sequences)")
    p.add_argument("--from", dest="kind", choices=("cube", "equirect"), default=None,
                   help="source kind (default: cube when SOURCE has {face} or is a folder, else equirect)")
    p.add_argument(
        "--preset", choices=("omnimax", "domemaster"), default="omnimax", help="dome frame (default omnimax)"
    )
    p.add_argument("--size", metavar="WxH", help="frame size (default 2048x1500 omnimax, 2048x2048 domemaster)")
    p.add_argument("--tilt", type=float, help="dome tilt in degrees (default 25 omnimax, 0 domemaster)")
    p.add_argument("--fov", type=float, help="field of view across the frame width, degrees (default 180)")
    p.add_argument("--lens", choices=("equidistant", "equisolid"), default="equidistant")
    p.add_argument("--lens-shift", type=float, help="lens centre below frame centre, in frame heights")
    p.add_argument("--supersample", type=int, default=2, help="directions per pixel along each axis (default 2)")
    p.add_argument("--frames", metavar="A-B", help="frame range substituted for {frame} in SOURCE and --out")


def load_source(source, kind, frame=None):
    """(6, n, n, C) cube faces or (H, W, C) equirect pixels from files."""
    from ..core.camera import dome
    from ..core.errors import DataError
    from ..fileio import read_image

    if kind == "equirect":
        return read_image(_path(source.format(frame=frame) if frame is not None else source))
    if Path(source).is_dir():
        pattern = str(Path(source) / "face_{face}.png")
    else:
        pattern = source
    faces = []
    for name in dome.CUBE_FACES:
        faces.append(read_image(_path(pattern.format(face=name, frame=frame))))
    shapes = {f.shape for f in faces}
    if len(shapes) != 1 or faces[0].shape[0] != faces[0].shape[1]:
        raise DataError(f"cube faces must be square and all the same size, got {sorted(shapes)}", path=pattern)
    return np.stack(faces)


def _path(p):
    p = Path(p)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such image")
    return p


def run(args):
    from ..core.camera import dome
    from ..fileio import write_image

    kind = args.kind or ("cube" if "{face}" in args.source or Path(args.source).is_dir() else "equirect")
    w, h = (None, None) if args.size is None else parse_size(args.size, example="2048x1500")
    frames = [None]
    if args.frames is not None:
        first, last = parse_range(args.frames)
        frames = list(range(first, last + 1))
    if args.frames and ("{frame" not in args.out or "{frame" not in args.source):
        raise UsageError("--frames needs {frame} (e.g. {frame:04d}) in SOURCE and --out")
    cam = dome.dome_camera(args.preset, width=w, height=h, fov=args.fov, tilt=args.tilt, lens=args.lens,
                           lens_shift=args.lens_shift)
    table = None
    for f in frames:
        src = load_source(args.source, kind, f)
        shape = src.shape[:3] if kind == "cube" else src.shape[:2]
        if table is None or table.source_shape != tuple(shape):
            table = dome.remap_table(cam, kind, shape, args.supersample)
        out = Path(args.out.format(frame=f) if f is not None else args.out)
        write_image(out, table.apply(src))
        print(f"{out}  ({cam.preset} {cam.width}x{cam.height} from {kind} {'x'.join(map(str, shape))})")
    return 0
