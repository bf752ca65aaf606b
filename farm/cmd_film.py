"""``nephele film --out out/film``: the paper's figures as one film, rendered through the farm.

One segment per figure in the paper's order, plus the dome (:mod:`.reel`):
each an example script rendered as a sequence by
:func:`nephele.farm.render.render_sequence` (resume, retries, logs and a
manifest per segment, on local workers, ``--scheduler`` or ``--slurm`` as
``nephele render``), all on one cluster.  Each segment opens with a title
card (figure number and caption); the climate segments carry the model date
and time and a legend (:mod:`nephele.addon.annotate_ops`).  The cut is laid
out in NumPy and encoded to H.264 by imageio-ffmpeg's ffmpeg:
``OUT/NAME.mp4``, ``OUT/contact_sheet.png`` (the title card, first, middle
and last frame of each segment) and ``OUT/film.json`` (timings, load).

    nephele film --out out/demo                      # preview: 480x270, 6 frames a segment
    nephele film --quality final --slurm --jobs 8    # 1920x1080, film length
    nephele film --only fig4                         # one segment
    nephele film --days 10                           # the 10-day climate film, one frame per model hour
"""

import json
import math
import os
import sys
import time
from pathlib import Path

from ..core.errors import UsageError
from ..core.parse import parse_size
from .cmd_render import add_cluster_arguments, cluster_kwargs, print_job_script

HELP = "render the paper's film: a segment per figure through the farm, title cards, an MP4 and a contact sheet"


def add_arguments(p):
    p.add_argument("--out", default="out/film", help="output folder (default out/film)")
    p.add_argument("--quality", choices=("preview", "final"), default="preview",
                   help="preview: 480x270, 6 frames a segment, few samples (default); final: 1920x1080, film length")
    p.add_argument("--only", metavar="FIGS", help="segments to render, e.g. fig4 or fig1,fig6 (fig1..fig7, dome)")
    p.add_argument("--days", type=float, help="the paper's climate film instead: Fig. 4's technique over DAYS model "
                                              "days, one frame per model hour (10 days: 240 frames)")
    p.add_argument("--no-annotations", action="store_true",
                   help="no title cards, captions, model times or legends: the rendered frames alone")
    p.add_argument("--frames", type=int, help="frames per segment (replaces the quality's)")
    p.add_argument("--size", metavar="WxH", help="frame size (replaces the quality's)")
    p.add_argument("--samples", type=int, help="samples per pixel (replaces the quality's)")
    p.add_argument("--source", default="demo", help='climate data of the globe segments (default "demo", embedded)')
    p.add_argument("--name", default="reel", help="the movie is OUT/NAME.mp4 (default reel)")
    f = p.add_argument_group("robustness")
    f.add_argument("--retries", type=int, default=2, help="extra attempts per failing frame (default 2)")
    f.add_argument("--timeout", type=float, help="seconds one frame may take before its worker is killed")
    f.add_argument("--quiet", action="store_true", help="no progress lines")
    add_cluster_arguments(p)


def check_days(days, source):
    """Frames of a ``days``-long film at one frame per model hour; :class:`UsageError` unless the data covers it."""
    from ..core.pipeline.sources import open_source

    if not (math.isfinite(days) and days > 0):
        raise UsageError(f"--days must be a positive number of model days, got {days:g}")
    hours = days * 24.0
    if abs(hours - round(hours)) > 1e-6:
        raise UsageError(f"--days {days:g} is not a whole number of model hours (one frame per hour)")
    have = float(open_source(source).hours[-1]) + 1.0  # frame k shows hour k - 1
    if round(hours) > have + 1e-6:
        raise UsageError(f"--days {days:g} needs {round(hours)} hours of data; {source} has {have:g}")
    return int(round(hours))


def _check(args):
    """Every input checked before anything renders; returns (shots, cluster kwargs, out folder)."""
    from ..core.pipeline.sources import open_source
    from . import reel
    from .render import check_out_dir

    if args.days is not None and args.only and args.only.strip().lower() != "fig4":
        raise UsageError("--days renders Fig. 4's technique: it cannot be combined with --only other segments")
    segments = reel.choose(None if args.days is not None else args.only)
    if args.frames is not None and args.frames < 1:
        raise UsageError(f"--frames must be >= 1, got {args.frames}")
    if args.samples is not None and args.samples < 1:
        raise UsageError(f"--samples must be >= 1, got {args.samples}")
    if args.retries < 0:
        raise UsageError(f"--retries must be >= 0, got {args.retries}")
    if args.timeout is not None and not args.timeout > 0:
        raise UsageError(f"--timeout must be > 0 seconds, got {args.timeout}")
    size = parse_size(args.size, "--size", example="1280x720", lo=16, hi=8192) if args.size else None
    if not args.name or "/" in args.name or args.name.startswith("."):
        raise UsageError(f"--name must be a plain file name, got {args.name!r}")
    if args.days is not None:
        check_days(args.days, args.source)
    elif any(s.climate for s in segments):
        open_source(args.source)  # bad data: one line now, not from a worker
    kwargs = cluster_kwargs(args)
    out = check_out_dir(args.out)
    for s in segments:
        if not (reel.EXAMPLES / s.script).is_file():
            raise UsageError(f"the example script is missing: {reel.EXAMPLES / s.script}")
    shots = reel.plan(out, args.quality, args.only, days=args.days, frames=args.frames, size=size,
                      samples=args.samples, annotate=not args.no_annotations, source=args.source)
    return shots, kwargs, out


def _resolution(shot):
    from .reel import dome_size

    return dome_size(shot.size) if shot.key == "dome" else tuple(shot.size)


def _say(args, text):
    if not args.quiet:
        print(f"nephele film: {text}", file=sys.stderr, flush=True)


def _bar(done, total, width=24):
    n = int(width * done / max(total, 1))
    return "[" + "#" * n + "-" * (width - n) + "]"


def render_shots(shots, kwargs, args, meter=None):
    """Render every shot on one cluster; returns ``{key: RenderResult}`` (stops at the first shot that fails).

    With ``meter`` (a :class:`~nephele.farm.cmd_demo.PeakMemory` running), each result gets ``cpu_seconds``:
    the CPU time all processes spent while that shot rendered."""
    from .cluster import open_client
    from .render import render_sequence

    total = sum(s.frames for s in shots)
    results, done, t0 = {}, 0, time.perf_counter()
    with open_client(workers=kwargs["workers"], scheduler=kwargs["scheduler"], security=kwargs["security"],
                     jobqueue=kwargs["jobqueue"], jobs=kwargs["jobs"]) as client:
        address = client.scheduler.address
        for i, shot in enumerate(shots, 1):
            _say(args, f"{_bar(done, total)} segment {i}/{len(shots)} {shot.title}: {shot.frames} frames "
                       f"-> {shot.out_dir}")
            cpu0 = meter.sample() if meter else 0.0
            res = render_sequence(shot.script, f"1-{shot.frames}", shot.out_dir, scheduler=address,
                                  security=kwargs["security"], engine=shot.engine, samples=shot.samples,
                                  resolution=_resolution(shot), scene_options=shot.options, cache_dir=shot.cache_dir,
                                  persistent=True,
                                  retries=args.retries, timeout=args.timeout, progress=not args.quiet)
            res.cpu_seconds = (meter.sample() - cpu0) if meter else None
            results[shot.key] = res
            done += shot.frames
            elapsed = time.perf_counter() - t0
            _say(args, f"{_bar(done, total)} {shot.key}: {len(res.rendered)} rendered, {len(res.skipped)} kept, "
                       f"{len(res.failed)} failed in {res.seconds:.1f} s; {done}/{total} frames, "
                       f"{elapsed:.0f} s so far")
            if not res.ok:
                break
    return results


def contact_sheet(stills, out_png, text, columns=4, thumb_width=240, gap=6):
    """Tile ``(label, (h, w, 3) sRGB)`` stills, ``columns`` a row, each labelled; written atomically."""
    import numpy as np

    from ..core.annotate.canvas import draw_text, new_canvas
    from ..fileio import write_image
    from .post import _resize

    h0, w0 = stills[0][1].shape[:2]
    tw, th = int(thumb_width), max(1, round(thumb_width * h0 / w0))
    rows = math.ceil(len(stills) / columns)
    sheet = new_canvas(columns * tw + (columns + 1) * gap, rows * th + (rows + 1) * gap)
    sheet[...] = (0.08, 0.08, 0.08, 1.0)
    for i, (label, rgb) in enumerate(stills):
        r, c = divmod(i, columns)
        y, x = gap + r * (th + gap), gap + c * (tw + gap)
        sheet[y : y + th, x : x + tw, :3] = np.clip(_resize(rgb.astype(np.float32), tw, th), 0.0, 1.0)
        if label:
            draw_text(sheet, text, label, max(9, th // 12), x + 4, y + th - 4 - round(1.3 * max(9, th // 12)))
    return write_image(out_png, sheet[..., :3])


def run(args):
    from . import reel

    shots, kwargs, out = _check(args)
    q = reel.QUALITIES[args.quality]
    if args.dry_run:
        for s in shots:
            print(f"{s.key}: {s.script.name} frames 1-{s.frames} {'x'.join(map(str, _resolution(s)))} "
                  f"engine {s.engine or 'scene'} samples {s.samples} -> {s.out_dir}\n  options {json.dumps(s.options)}")
        if kwargs["jobqueue"]:
            print_job_script(kwargs["jobqueue"], kwargs["security"])
        return 0
    from .cmd_demo import PeakMemory

    load0, t0 = os.getloadavg(), time.perf_counter()
    meter = PeakMemory(interval=0.5)
    with meter:
        code = _film(args, shots, kwargs, out, q, meter)
    if code:
        return code
    summary_path = out / "film.json"
    summary = json.loads(summary_path.read_text())
    summary.update(seconds=round(time.perf_counter() - t0, 1), cpu_seconds=round(meter.cpu_seconds, 1),
                   peak_memory_mb=round(meter.peak_total / 2**20),
                   load_average_start=[round(v, 2) for v in load0],
                   load_average_end=[round(v, 2) for v in os.getloadavg()], cpus=os.cpu_count())
    _write_json(summary_path, summary)
    print(f"nephele film: {out / summary['movie']} ({summary['seconds_of_film']:.1f} s of film, "
          f"{len(shots)} segments, {summary['rendered']} frames rendered, {summary['kept']} kept) and "
          f"{out / summary['contact_sheet']} in {summary['seconds']:.0f} s, {summary['cpu_seconds']:.0f} CPU s "
          f"(load {load0[0]:.1f} at the start on {os.cpu_count()} CPUs)", file=sys.stderr)
    return 0


def _round(value, digits=1):
    return None if value is None else round(value, digits)


def _write_json(path, data):
    from ..core.files import atomic_write

    with atomic_write(path) as tmp, open(tmp, "w") as f:
        json.dump(data, f, indent=1)


def _film(args, shots, kwargs, out, q, meter=None):
    """Title cards, the segments' frames, the movie and the contact sheet; writes ``film.json``."""
    from ..fileio import text_mask, write_image
    from . import reel
    from .post import encode

    t0 = time.perf_counter()
    cards = {}
    if not args.no_annotations:
        for s in shots:
            cards[s.key] = reel.card(s, s.size, text_mask)
            write_image(out / "cards" / f"{s.key}.png", cards[s.key])
    results = render_shots(shots, kwargs, args, meter)
    failed = {k: r for k, r in results.items() if not r.ok}
    if failed or len(results) < len(shots):
        for key, r in failed.items():
            print(f"nephele film: {key}: FAILED frames:", file=sys.stderr)
            for line in r.failure_report():
                print("  " + line, file=sys.stderr)
        return 1
    t_render = time.perf_counter() - t0
    paths = {k: r.paths for k, r in results.items()}
    size = tuple(shots[0].size)
    stills, picks = [], {}
    for s in shots:
        n = len(paths[s.key])
        picks[s.key] = {paths[s.key][i] for i in sorted({0, n // 2, n - 1})}
        if s.key in cards:
            stills.append((s.key, cards[s.key]))

    def keep(stream):
        for label, rgb in stream:
            for key, chosen in picks.items():
                if label in chosen:
                    chosen.discard(label)
                    stills.append((f"{key} {Path(label).stem.replace('frame_', '')}", rgb.astype("float32") / 255.0))
            yield label, rgb

    movie = out / f"{args.name}.mp4"
    encode(keep(reel.pictures(shots, paths, cards, size, q["fps"], q["hold"], q["title_s"], q["tail_s"])), movie,
           fps=q["fps"])
    columns = 4 if cards else 3
    sheet = contact_sheet(stills, out / "contact_sheet.png", text_mask, columns=columns)
    n_pictures = reel.reel_length(shots, cards, q["fps"], q["hold"], q["title_s"], q["tail_s"])
    summary = {
        "quality": args.quality, "size": list(size), "fps": q["fps"],
        "seconds_of_film": round(n_pictures / q["fps"], 2),
        "movie": movie.name, "contact_sheet": Path(sheet).name, "annotations": not args.no_annotations,
        "render_seconds": round(t_render, 1), "cut_seconds": round(time.perf_counter() - t0 - t_render, 1),
        "rendered": sum(len(r.rendered) for r in results.values()),
        "kept": sum(len(r.skipped) for r in results.values()),
        "segments": [{"key": s.key, "title": s.title, "frames": s.frames, "folder": str(s.out_dir.relative_to(out)),
                      "rendered": len(results[s.key].rendered), "kept": len(results[s.key].skipped),
                      "seconds": round(results[s.key].seconds, 1),
                      "cpu_seconds": _round(results[s.key].cpu_seconds),
                      "seconds_per_rendered_frame": round(results[s.key].seconds / len(results[s.key].rendered), 2)
                      if results[s.key].rendered else None,
                      "options": s.options, "engine": s.engine, "samples": s.samples} for s in shots],
    }
    _write_json(out / "film.json", summary)
    return 0
