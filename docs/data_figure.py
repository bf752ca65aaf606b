"""Draw docs/images/data.png for the README: the demo climate's clouds moving with its winds,
and cloud fraction derived from the real GrADS sample (Sundqvist scheme).

    .venv/bin/python docs/data_figure.py [--shared tests/data]
"""

import argparse
import os
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LinearSegmentedColormap  # noqa: E402

from nephele.core.climate.readers import open_dataset  # noqa: E402
from nephele.core.climate.relief import load_relief  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
EARTH = LinearSegmentedColormap.from_list("earth", ["#1d3f6e", "#3c6e9c", "#6f9d6a", "#a99a6b", "#e8e2d0"])


def relief_image():
    lon, lat, z = load_relief()
    # Sea in blues by depth, land in greens/browns by height, on one ramp split at sea level.
    return np.where(z < 0, 0.25 * np.clip(1 + z / 6000, 0, 1), 0.5 + 0.5 * np.clip(z / 5000, 0, 1))


def panel(ax, grid, cloud, title, u=None, v=None, background=None):
    ext = [grid.lon[0], grid.lon[-1], grid.lat[0], grid.lat[-1]]
    if background is not None:
        ax.imshow(background, origin="lower", extent=[0, 360, -90, 90], cmap=EARTH, vmin=0, vmax=1, aspect="auto")
    rgba = np.ones(cloud.shape + (4,))
    rgba[..., 3] = np.nan_to_num(np.clip(cloud, 0, 1)) * 0.9
    ax.imshow(rgba, origin="lower", extent=ext, aspect="auto", interpolation="bilinear")
    ax.contour(grid.lon, grid.lat, np.nan_to_num(cloud), [0.15], colors="#ffcc33", linewidths=0.6)
    if u is not None:
        si, sj = max(1, grid.lon.size // 36), max(1, grid.lat.size // 18)
        ax.quiver(grid.lon[::si], grid.lat[sj // 2 :: sj], u[sj // 2 :: sj, ::si], v[sj // 2 :: sj, ::si],
                  color="#ff5533", scale=450, width=0.002)
    ax.set_xlim(0, 360)
    ax.set_ylim(-90, 90)
    ax.set_xticks(range(0, 361, 60))
    ax.set_yticks(range(-90, 91, 30))
    ax.tick_params(labelsize=7)
    ax.set_title(title, fontsize=9)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--shared", default=str(ROOT / "tests" / "data"))
    parser.add_argument("--out", default=str(ROOT / "docs" / "images" / "data.png"))
    args = parser.parse_args()
    demo = open_dataset("demo")
    k = 4
    bg = relief_image()
    fig, axes = plt.subplots(2, 2, figsize=(11, 5.8), constrained_layout=True)
    for ax, t in zip(axes.flat[:3], (0, 96, 192)):
        u, v, _ = demo.wind(t)
        h = demo.grid.height[k]
        panel(ax, demo.grid, demo.read("cloud", t)[k],
              f"demo climate, level {k} ({h.min() / 1000:.1f}-{h.max() / 1000:.1f} km), "
              f"{np.datetime_as_string(demo.times[t], unit='h')}", u[k], v[k], bg)
    ctl = Path(args.shared) / "climate" / "model.ctl"
    ax = axes.flat[3]
    if ctl.is_file():
        grads = open_dataset(ctl)
        u, v, _ = grads.wind(0)
        panel(ax, grads.grid, grads.read("cloud", 0)[2],
              "GrADS sample, 700 hPa, 1987-01-02: cloud from RH (Sundqvist, RH_c 0.8)", u[2], v[2], bg)
    else:
        ax.set_axis_off()
    fig.suptitle("Cloud fraction (white; yellow: 15 % contour) and wind (red arrows) over the ETOPO60 relief",
                 fontsize=10)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, suffix=".png")
    os.close(fd)
    fig.savefig(tmp, dpi=90)
    os.chmod(tmp, 0o644)
    os.replace(tmp, out)
    print(out)


if __name__ == "__main__":
    main()
