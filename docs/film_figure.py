"""Docs pictures of the paper's film from a rendered reel (``nephele film`` / ``make demo``).

Writes, each a small JPEG: ``docs/images/film_contact_sheet.jpg`` (the reel's contact sheet, reduced),
``docs/images/film_frames.jpg`` (the middle frame of every segment, taken back out of the MP4, two a row)
and, given ``--final DIR`` (a ``nephele film --quality final --frames 1`` folder),
``docs/images/film_final.jpg`` (each segment's final-quality frame, reduced).

    .venv/bin/python docs/film_figure.py out/demo [--final out/film_final]
"""

import argparse
import json
from pathlib import Path

import numpy as np

from nephele.farm.post import _resize, read_rgba
from nephele.farm.reel import QUALITIES
from nephele.fileio import write_image

ROOT = Path(__file__).resolve().parent.parent
IMAGES = ROOT / "docs" / "images"


def reduced(rgb, width):
    h, w = rgb.shape[:2]
    return np.clip(_resize(rgb.astype(np.float32), width, round(h * width / w)), 0.0, 1.0) if w > width else rgb


def movie_frames(folder):
    """The middle picture of each segment's frames in the MP4 (the encoder's output, not the PNGs)."""
    import imageio_ffmpeg

    s = json.loads((folder / "film.json").read_text())
    q = QUALITIES[s["quality"]]
    reader = imageio_ffmpeg.read_frames(str(folder / s["movie"]))
    w, h = next(reader)["size"]
    pictures = [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in reader]
    title = (round(q["title_s"] * s["fps"]) + round(0.5 * s["fps"])) if s["annotations"] else 0
    out, i = [], 0
    for seg in s["segments"]:
        n = seg["frames"] * q["hold"]
        out.append(pictures[i + title + n // 2].astype(np.float32) / 255.0)
        i += title + n + round(q["tail_s"] * s["fps"])
    return out


def grid(images, columns=2, gap=4):
    rows = [np.concatenate(sum(([im, np.zeros((im.shape[0], gap, 3), np.float32)] for im in images[r:r + columns]),
                               [])[:-1], axis=1) for r in range(0, len(images), columns)]
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, gap), (0, width - r.shape[1]), (0, 0))) for r in rows]
    return np.concatenate(rows, axis=0)[:-gap]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("reel", type=Path, help="a preview reel's folder (film.json, reel.mp4, contact_sheet.png)")
    ap.add_argument("--final", type=Path,
                    help="a folder of final-quality frames (nephele film --quality final --frames 1)")
    args = ap.parse_args(argv)
    sheet = read_rgba(args.reel / "contact_sheet.png")[..., :3]
    print(write_image(IMAGES / "film_contact_sheet.jpg", reduced(sheet, 960), compression="jpeg:82"))
    print(write_image(IMAGES / "film_frames.jpg", grid(movie_frames(args.reel)), compression="jpeg:82"))
    if args.final:
        s = json.loads((args.final / "film.json").read_text())
        finals = [reduced(read_rgba(args.final / seg["folder"] / "frame_0001.png")[..., :3], 480)
                  for seg in s["segments"]]
        print(write_image(IMAGES / "film_final.jpg", grid(finals), compression="jpeg:85"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
