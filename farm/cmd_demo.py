"""``nephele demo --out out/demo``: a short film of Fig. 1 from the embedded climate.

Builds the scene of ``examples/fig1_contours.py`` (contour surfaces of 15%
cloudiness over the relief globe, following model time) into
``OUT/fig1.blend`` in a separate Blender process, renders it headless with
Cycles on the CPU through :func:`nephele.farm.render.render_sequence` (the
workers open the .blend and call only ``frame.install()``; the contour meshes
are cached in ``OUT/fig1_nephele_cache``), then tiles the frames into
``contact_sheet.png`` with OpenImageIO.  The peak
memory of the whole process tree (this process, the Dask scheduler and the
bpy workers; resident set sizes summed, an upper bound) is sampled while it
runs and written with the timings to ``demo.json``.
"""

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

from ..core.errors import UsageError
from ..core.parse import parse_size

HELP = "render the Fig. 1 demo film (embedded data) to PNG frames and a contact sheet"

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "examples" / "fig1_contours.py"


def add_arguments(p):
    p.add_argument("--out", default="out/demo", help="output directory (default: out/demo)")
    p.add_argument("--frames", default="1-24", help="frames, e.g. 1-24")
    p.add_argument("--size", default="320x240", help="WxH (default 320x240)")
    p.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel (default 16)")
    p.add_argument("--workers", type=int, default=None, help="local Dask workers (default: the farm's)")
    p.add_argument("--source", default="demo", help='data: "demo" (default), "demo:small", a .nc or .ctl file')
    p.add_argument("--hours-per-frame", type=float, default=6.0,
                   help="model hours per frame (default 6: 24 frames show six days)")
    p.add_argument("--haze", choices=("none", "shell", "volume"), default="none",
                   help="blue haze: none (default), a closed-form shell (cheap) or a volume (about 3x slower)")


class PeakMemory:
    """Samples the summed memory of this process and all its descendants.

    ``peak_total`` sums resident set sizes (pages shared between processes
    counted in each: an upper bound); ``peak_pss`` sums proportional set sizes
    (shared pages split between their users), where the system reports them.
    ``cpu_seconds`` sums the CPU time (user + system) each process had used
    when last seen: a process's last ``interval`` before it ended is missed.
    """

    def __init__(self, interval=0.25):
        self.interval = interval
        self.peak_total = 0
        self.peak_pss = 0
        self.peak_process = 0
        self._cpu = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _sample(self):
        import psutil

        me = psutil.Process()
        total = pss = 0
        for p in [me] + me.children(recursive=True):
            try:
                info = p.memory_full_info()
                times = p.cpu_times()
                key = (p.pid, p.create_time())
            except (psutil.NoSuchProcess, psutil.AccessDenied):
                continue
            self._cpu[key] = max(self._cpu.get(key, 0.0), times.user + times.system)
            total += info.rss
            pss += getattr(info, "pss", info.rss)
            self.peak_process = max(self.peak_process, info.rss)
        self.peak_total = max(self.peak_total, total)
        self.peak_pss = max(self.peak_pss, pss)

    @property
    def cpu_seconds(self):
        return sum(self._cpu.values())

    def sample(self):
        """Sample now; returns :attr:`cpu_seconds`."""
        self._sample()
        return self.cpu_seconds

    def _run(self):
        while not self._stop.is_set():
            self._sample()
            self._stop.wait(self.interval)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self._sample()


def _write_json(path, data):
    from ..core.files import atomic_write

    with atomic_write(path) as tmp, open(tmp, "w") as f:
        json.dump(data, f, indent=2)


def build_blend(out, options):
    """``OUT/fig1.blend`` built by the example script in a fresh process (reused when the options match)."""
    blend = out / "fig1.blend"
    stamp = out / "fig1.json"
    if blend.is_file() and stamp.is_file() and json.loads(stamp.read_text()) == options:
        return blend
    cmd = [sys.executable, str(SCRIPT), "--save", str(blend), "--source", options["source"],
           "--frames", "{}-{}".format(*options["frames"]), "--size", "{}x{}".format(*options["size"]),
           "--samples", str(options["samples"]), "--hours-per-frame", repr(options["hours_per_frame"]),
           "--haze", options["haze"]]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0 or not blend.is_file():
        tail = "\n".join((res.stdout + res.stderr).strip().splitlines()[-5:])
        raise UsageError(f"building the Fig. 1 scene failed ({res.returncode}): {tail}")
    _write_json(stamp, options)
    return blend


def run(args):
    from ..core.errors import DataError
    from ..core.pipeline.sources import open_source
    from .frames import parse_frames
    from .post import contact_sheet
    from .render import render_sequence

    size = parse_size(args.size, lo=8, hi=8192)
    if args.samples < 1:
        raise UsageError(f"--samples must be >= 1, got {args.samples}")
    if not args.hours_per_frame > 0:
        raise UsageError(f"--hours-per-frame must be > 0, got {args.hours_per_frame}")
    if not SCRIPT.is_file():
        raise UsageError(f"the Fig. 1 example script is missing: {SCRIPT}")
    frames = parse_frames(args.frames)
    ds = open_source(args.source)  # bad data fails here, before any worker starts
    if "cloud" not in ds:  # the demo film contours cloudiness
        raise DataError(f"has no cloud fraction to contour (fields: {', '.join(sorted(ds.variables))})",
                        path=ds.source, field="cloud")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    options = {
        "source": args.source,
        "frames": [min(frames), max(frames)],
        "size": list(size),
        "samples": args.samples,
        "hours_per_frame": args.hours_per_frame,
        "haze": args.haze,
    }
    t0 = time.perf_counter()
    with PeakMemory() as mem:
        blend = build_blend(out, options)
        result = render_sequence(blend, frames, out, workers=args.workers, engine="CYCLES", samples=args.samples,
                                 resolution=size, device="CPU")
    seconds = time.perf_counter() - t0
    if not result.ok:
        for line in result.failure_report():
            print(line)
        raise UsageError(f"{len(result.failed)} of {len(frames)} frames failed")
    sheet = contact_sheet(result.paths, out / "contact_sheet.png", columns=min(6, len(frames)))
    summary = {
        "frames": len(frames),
        "rendered": len(result.rendered),
        "skipped": len(result.skipped),
        "size": list(size),
        "samples": args.samples,
        "seconds": round(seconds, 1),
        "peak_memory_total_mb": round(mem.peak_total / 2**20),
        "peak_memory_pss_mb": round(mem.peak_pss / 2**20),
        "peak_memory_one_process_mb": round(mem.peak_process / 2**20),
        "contact_sheet": str(Path(sheet).name if sheet else "contact_sheet.png"),
        "scene": blend.name,
        "options": options,
    }
    _write_json(out / "demo.json", summary)
    print(f"{len(frames)} frames in {out} ({len(result.rendered)} rendered, {len(result.skipped)} kept) "
          f"in {seconds:.0f} s; peak memory {summary['peak_memory_total_mb']} MB resident summed over all processes "
          f"({summary['peak_memory_pss_mb']} MB proportional); "
          f"contact sheet {out / 'contact_sheet.png'}")
    return 0
