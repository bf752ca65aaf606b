"""The paper's film: one segment per figure, rendered through the farm, cut together with title cards.

:data:`SEGMENTS` lists the figures in the paper's order (and the dome): which
example script builds the scene, what moves in it, and the build options of a
preview and a final reel.  :func:`plan` turns a quality and a choice of
segments into :class:`Shot` s (the example, its options, frames, render
overrides, output folder); :mod:`.cmd_film` renders each with
:func:`nephele.farm.render.render_sequence`, so frames resume, retry and run
on any Dask cluster as ``nephele render``'s do.  :func:`pictures` then lays
the reel out as NumPy frames (a title card held, each rendered frame shown
``hold`` times, the last one held), which :func:`nephele.farm.post.encode`
pipes into the ffmpeg that imageio-ffmpeg bundles.  Nothing of the cut is
rendered by Blender.
"""

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.annotate import FIGURES, REFERENCE, title_card
from ..core.errors import UsageError

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


@dataclass(frozen=True)
class Segment:
    """One figure of the reel: ``script`` (in ``examples/``) builds it; ``motion`` says what moves."""

    key: str
    script: str
    motion: str
    climate: bool = True


SEGMENTS = (
    Segment("fig1", "fig1_contours.py", "the 15% cloudiness contours follow the model hours"),
    Segment("fig2", "fig2_volume.py", "the volume-rendered clouds change with the model hours"),
    Segment("fig3", "fig3_splats.py", "texture splats whose streaks flow along the wind"),
    Segment("fig4", "fig4_advected_texture.py", "a transparency texture carried by the wind, traced back hour by hour"),
    Segment("fig5", "fig5_flow_volume.py", "smoke released from a generator and carried by the winds"),
    Segment("fig6", "fig6_scattering.py", "the camera orbits a cloud lit by multiple scattering", climate=False),
    Segment("fig7", "fig7_muscle.py", "myosin cross-bridges cycle along the actin filaments", climate=False),
    Segment("dome", "dome_omnimax.py", "an Omnimax frame sequence: the globe counter-distorted for a tilted dome"),
)
KEYS = tuple(s.key for s in SEGMENTS)

# A preview renders volumes with Cycles' biased ray marching: the unbiased (null scattering) default builds a
# majorant grid every frame, ~6 CPU s of a Fig. 6 frame's 8 here (biased: 0.3 s), for ~2.5% darker clouds.
QUALITIES = {
    # size, frames per segment, model hours per frame, samples, film rate, shows per rendered frame,
    # seconds of title card and of the last frame held
    "preview": dict(size=(480, 270), frames=6, hours_per_frame=3.0, samples=2, fps=24, hold=4, title_s=1.5,
                    tail_s=0.25),
    "final": dict(size=(1920, 1080), frames=240, hours_per_frame=1.0, samples=32, fps=24, hold=1, title_s=4.0,
                  tail_s=1.0),
}


FINAL_FIG6_GRID = (64, 64, 48)  # one solve for the orbit: 2.4 s on 2 cores (docs/benchmarks.md, scatter-compiled)


@dataclass
class Shot:
    """What one segment renders: the example, its ``build()`` options, frames and render overrides."""

    segment: Segment
    title: str
    options: dict
    frames: int
    engine: str = None
    samples: int = None
    size: tuple = (480, 270)
    out_dir: Path = None
    cache_dir: Path = None
    lines: list = field(default_factory=list)

    @property
    def script(self):
        return EXAMPLES / self.segment.script

    @property
    def key(self):
        return self.segment.key


def choose(only=None):
    """The segments named in ``only`` (``"fig1,fig4"``; keys of :data:`KEYS`), in the paper's order; all by default."""
    if not only:
        return list(SEGMENTS)
    names = [n.strip().lower() for n in str(only).split(",") if n.strip()]
    unknown = [n for n in names if n not in KEYS]
    if unknown or not names:
        raise UsageError(f"--only: unknown figure {', '.join(unknown) or repr(only)}; choose from {', '.join(KEYS)}")
    return [s for s in SEGMENTS if s.key in names]


def _camera_distance(key, size):
    """The figure's camera distance, moved back for a frame wider than the 4:3 it was framed in (the globe whole)."""
    from ..addon import presets

    default = getattr(presets, f"{key.upper()}_DEFAULTS")["camera_distance"]
    return round(default * max(1.0, (size[0] / size[1]) / (4.0 / 3.0)), 4)


def _options(seg, q, frames, hpf, size, samples, annotate, source, cache):
    """``build()`` options of ``seg``'s example for a reel of quality settings ``q``."""
    preview = q["size"][1] < 720
    climate = {"source": source, "frames": [1, frames], "hours_per_frame": hpf, "size": list(size),
               "samples": samples, "annotations": annotate}
    if seg.key in ("fig1", "fig2", "fig3", "fig4", "fig5"):
        climate["camera_distance"] = _camera_distance(seg.key, size)
    if seg.key == "fig1":
        return {**climate, "haze": "shell" if preview else "volume"}
    if seg.key == "fig2":  # a preview: coarser voxels, one bounce (the exact shader costs ~5x, 4 bounces ~3x)
        return {**climate, "vdb_dir": str(cache / "vdb"), "haze": not preview,
                **({"mode": "voxels", "voxel_size": 0.006, "volume_bounces": 1, "volume_biased": True}
                   if preview else {})}
    if seg.key == "fig3":
        return climate
    if seg.key == "fig4":  # a preview composes one-frame maps: a constant cost a frame (restart grows to 24 frames')
        return {**climate, "haze": not preview, **({"strategy": "compose"} if preview else {})}
    if seg.key == "fig5":  # the release grows frame by frame: the smoke leaves the generator and is carried on
        return {**climate, "hours": frames * hpf, "grow": True, **({"volume_biased": True} if preview else {})}
    if seg.key == "fig6":  # final: 64x64x48, as the Fig. 6 docs advise for films (against Cycles, 128x96 at 16384
        # spp: 4x4 blocks 1.9 % off instead of the paper's 24x24x18's 5.9 %, mean -0.0 % instead of +2.7 %)
        return {"frames": frames, "size": list(size), "samples": samples, "directory": str(cache / "vdb"),
                "annotations": annotate, **({"volume_biased": True} if preview else {"grid": list(FINAL_FIG6_GRID)})}
    if seg.key == "fig7":
        return {"film_frames": frames, "size": list(size), "samples": samples, "annotations": annotate,
                **({"spacing": 1.4, "max_bounces": 3} if preview else {})}
    # the dome: an Omnimax frame (the paper's Fig. 7 format), the globe's clouds following the hours
    return {"preset": "omnimax", "stereo": False, "source": source, "frames": [1, frames],
            "hours_per_frame": hpf, "size": list(dome_size(size)), "samples": samples}


def dome_size(size):
    """The Omnimax frame (2048:1500) as tall as the reel's frame, width even."""
    h = int(size[1])
    return 2 * round(h * 2048 / 1500 / 2), h


def plan(out, quality="preview", only=None, *, days=None, frames=None, size=None, samples=None, annotate=True,
         source="demo"):
    """The shots of a reel, each with its own output folder under ``out/frames``.

    ``days``: instead, the paper's climate film, Fig. 4's technique over that
    many model days at one frame per model hour.  ``frames``, ``size``,
    ``samples`` replace the quality's.  A shot's folder is named after a hash
    of everything that changes its pictures, so a resumed reel keeps only
    frames made with the same options.
    """
    q = QUALITIES[quality]
    size = tuple(size or q["size"])
    samples_given = samples
    samples = int(samples or q["samples"])
    shots = []
    if days is not None:
        segs, hpf, n = [next(s for s in SEGMENTS if s.key == "fig4")], 1.0, int(round(days * 24))
    else:
        segs, hpf, n = choose(only), q["hours_per_frame"], int(frames or q["frames"])
    for seg in segs:
        count = n
        if seg.key == "fig6" and days is None and frames is None and quality == "final":
            count = 120  # the paper's orbit
        cache = Path(out) / "cache" / seg.key
        options = _options(seg, q, count, hpf, size, samples, annotate, source, cache)
        number, caption = FIGURES[seg.key]
        title = f"{number}  {caption}"
        lines = [seg.motion, REFERENCE]
        if days is not None:
            lines[0] = f"{days:g} model days, one frame per model hour: the texture moves with the wind"
        # splats: EEVEE draws them as the paper's hardware did (tests/addon/test_splat_ops.py: within 2 % of the
        # core renderer), ~7x faster than Cycles at 1 sample; a final Cycles frame (1920x1080, 32 samples) ran
        # past 23 min on 2 cores without finishing (2026-11-29), so a final reel draws them with EEVEE too
        engine = "BLENDER_EEVEE" if seg.key == "fig3" else None
        n_samples = samples
        if samples_given is None and quality == "preview":  # the denoiser cleans 2 samples; Fig. 7 has none
            n_samples = 1 if engine == "BLENDER_EEVEE" else 4 if seg.key == "fig7" else samples
        shot = Shot(seg, title, options, count, engine=engine, samples=n_samples, size=size, cache_dir=cache,
                    lines=lines)
        shot.out_dir = Path(out) / "frames" / f"{seg.key}-{fingerprint(shot)}"
        shots.append(shot)
    return shots


def fingerprint(shot):
    """8 hex digits naming what a shot's frames depend on (script, options, overrides)."""
    what = {"script": shot.segment.script, "options": shot.options, "engine": shot.engine, "samples": shot.samples,
            "size": list(shot.size), "frames": shot.frames}
    return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:8]


def card(shot, size, text):
    """The title card of a shot, ``(h, w, 3)`` float sRGB."""
    number, caption = FIGURES[shot.key]
    return title_card(size[0], size[1], text, number=number, caption=caption, lines=shot.lines)


def fit(rgb, size):
    """``rgb`` centred on a black frame of ``size`` (a square dome frame in a 16:9 reel)."""
    w, h = size
    ih, iw = rgb.shape[:2]
    if (iw, ih) == (w, h):
        return rgb
    out = np.zeros((h, w, 3), rgb.dtype)
    y, x = max(0, (h - ih) // 2), max(0, (w - iw) // 2)
    out[y : y + min(ih, h), x : x + min(iw, w)] = rgb[: min(ih, h), : min(iw, w)]
    return out


def to_bytes(rgb):
    return np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)


def pictures(shots, paths, cards, size, fps=24, hold=2, title_s=1.5, tail_s=0.25, read=None):
    """The reel's pictures in order, as ``(label, uint8 rgb)`` pairs for :func:`nephele.farm.post.encode`.

    Per shot: its title card (``cards[key]``, None for none) for ``title_s``
    seconds, a half-second cross-fade into the first frame, every frame
    ``hold`` times, the last frame ``tail_s`` seconds more.  ``paths[key]``
    are the shot's frames; ``read(path)`` gives a frame's ``(h, w, 3)``
    float sRGB (default: OpenImageIO through :func:`nephele.farm.post.read_rgba`).
    """
    if read is None:
        from .post import read_rgba

        def read(p):
            return read_rgba(p)[..., :3]  # premultiplied: over black

    for shot in shots:
        frames = paths[shot.key]
        first = fit(read(frames[0]), size)
        c = cards.get(shot.key)
        if c is not None:
            still = to_bytes(c)
            for _ in range(int(round(title_s * fps))):
                yield f"{shot.key} title card", still
            steps = int(round(0.5 * fps))
            for i in range(1, steps + 1):
                t = i / (steps + 1)
                yield f"{shot.key} fade", to_bytes(c * (1.0 - t) + first * t)
        for k, p in enumerate(frames):
            rgb = to_bytes(first if k == 0 else fit(read(p), size))
            for _ in range(hold):
                yield p, rgb
        for _ in range(int(round(tail_s * fps))):
            yield frames[-1], rgb


def reel_length(shots, cards, fps=24, hold=2, title_s=1.5, tail_s=0.25):
    """Pictures in the reel :func:`pictures` lays out."""
    n = 0
    for shot in shots:
        if cards.get(shot.key) is not None:
            n += int(round(title_s * fps)) + int(round(0.5 * fps))
        n += shot.frames * hold + int(round(tail_s * fps))
    return n


__all__ = ["KEYS", "QUALITIES", "SEGMENTS", "Segment", "Shot", "card", "choose", "fingerprint", "fit", "pictures",
           "plan", "reel_length"]
