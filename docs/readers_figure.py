"""Draw docs/images/readers.png for the README: real model files placed on the globe by their own grids.

(a) The UM rotated-pole file: where its grid lands with the rotation (over Wales) and where its
rotated coordinates alone would put it (Gulf of Guinea).  (b) The polar stereographic satellite
file (tests/data) at the longitudes/latitudes of its inverse projection, over the shipped relief's
coastline.  (c) The CAM history file: heights of its hybrid sigma-pressure levels along the
equator, from its own coefficients and surface pressure (terrain following near the ground, flat
aloft).

    .venv/bin/python docs/readers_figure.py
"""

import os
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

from nephele.core.climate.netcdf import projected_lonlat  # noqa: E402
from nephele.core.climate.readers import open_dataset  # noqa: E402
from nephele.core.climate.relief import load_relief  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"


def _coast(ax, lon_range, lat_range):
    lon, lat, z = load_relief()
    lon = np.where(lon > 180, lon - 360, lon)
    order = np.argsort(lon)
    ax.contour(lon[order], lat, z[:, order], levels=[0.0], colors="0.35", linewidths=0.6)
    ax.set_xlim(*lon_range)
    ax.set_ylim(*lat_range)


def main():
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    # (a) UM rotated pole
    ax = axes[0]
    um = open_dataset(DATA / "um_hybrid_height.nc")
    tlon, tlat = um.grid.true_lonlat()
    theta = um.read("air_potential_temperature", 0)[0]
    _coast(ax, (-25, 15), (-10, 60))
    m = ax.pcolormesh(tlon, tlat, theta, shading="auto", cmap="inferno")
    box = lambda lo, la: ax.plot(np.r_[lo[0], lo[-1], lo[-1], lo[0], lo[0]],  # noqa: E731
                                 np.r_[la[0], la[0], la[-1], la[-1], la[0]], lw=1.5)
    glon = np.where(um.grid.lon > 180, um.grid.lon - 360, um.grid.lon)
    box(glon, um.grid.lat)
    ax.plot([tlon.mean()], [tlat.mean()], "o", ms=9, mfc="none", mec="C3", mew=2)
    ax.annotate("with the rotation:\n52.4 N 3.1 W (Wales)", (tlon.mean(), tlat.mean()), (-23, 40),
                arrowprops={"arrowstyle": "->"})
    ax.annotate("grid coordinates alone:\n0.1 S 0.4 W", (glon.mean(), um.grid.lat.mean()), (-23, 8),
                arrowprops={"arrowstyle": "->"})
    ax.set_title("(a) UM rotated pole (pole 37.5 N 177.5 E)")
    fig.colorbar(m, ax=ax, shrink=0.8, label="potential temperature, lowest level (K)")
    # (b) polar stereographic satellite brightness at its projected positions
    ax = axes[1]
    with xr.open_dataset(DATA / "toa_brightness_stereographic.nc") as f:
        lon, lat, _ = projected_lonlat(dict(f["stereographic"].attrs), f["x"].values, f["y"].values)
        data = f["data"].values
    _coast(ax, (-110, 40), (10, 85))
    m = ax.pcolormesh(lon, lat, np.ma.masked_invalid(data), shading="auto", cmap="Greys_r")
    ax.set_title("(b) polar stereographic (tests/data, x/y -> lon/lat)")
    fig.colorbar(m, ax=ax, shrink=0.8, label="TOA brightness temperature (K)")
    # (c) CAM hybrid level heights along the equator
    ax = axes[2]
    cam = open_dataset(DATA / "cam_vinth2p.nc")
    j = int(np.argmin(np.abs(cam.grid.lat)))
    h = cam.grid.height[:, j, :] / 1000.0
    for k in range(h.shape[0]):
        ax.plot(cam.grid.lon, h[k], lw=0.8, color="C0")
    ax.set_ylim(-0.5, 20)
    ax.set_xlabel("longitude (E)")
    ax.set_ylabel("height (km)")
    ax.set_title("(c) CAM hybrid levels along the equator")
    fig.tight_layout()
    out = ROOT / "docs" / "images" / "readers.png"
    fd, tmp = tempfile.mkstemp(dir=out.parent, suffix=".png")
    os.close(fd)
    fig.savefig(tmp, dpi=80)
    os.replace(tmp, out)
    print(out)


if __name__ == "__main__":
    main()
