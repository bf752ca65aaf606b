import numpy as np
import pytest

from nephele.core.climate.relief import RELIEF_FILE, load_etopo, load_relief, sample_relief, write_relief
from nephele.core.errors import DataError


def test_shipped_relief_is_small_and_plausible():
    assert RELIEF_FILE.stat().st_size < 200_000
    lon, lat, z = load_relief()
    assert z.shape == (180, 360) and lon.shape == (360,) and lat.shape == (180,)
    assert np.all(np.diff(lon) > 0) and np.all(np.diff(lat) > 0)
    assert 0 <= lon[0] and lon[-1] < 360
    # Himalaya / Tibet high, Pacific deep, Antarctic plateau high.
    assert sample_relief(87.0, 30.0) > 3000
    assert sample_relief(-150.0, 0.0) < -3000
    assert sample_relief(0.0, -85.0) > 2000
    assert 0.25 < np.mean(z > 0) < 0.35  # about 29 % of the Earth is land


def test_shipped_relief_reproduces_from_etopo60(shared_data, tmp_path):
    out = write_relief(shared_data / "terrain" / "etopo60.cdf", tmp_path / "r.npz")
    a, b = load_relief(out), load_relief()
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_etopo_20_and_60_agree(shared_data):
    lon20, lat20, z20 = load_etopo(shared_data / "terrain" / "etopo20.cdf")
    assert z20.shape == (540, 1080)  # seam column of the 1081-column file dropped
    assert np.all(np.diff(lon20) > 0) and lon20[-1] < 360
    # 3×3 block means of the 20' grid are close to the 60' grid (same source data).
    lon60, lat60, z60 = load_etopo(shared_data / "terrain" / "etopo60.cdf")
    coarse = z20.reshape(180, 3, 360, 3).mean(axis=(1, 3))
    shift = int(round((lon60[0] - lon20[1]) / 1.0))  # both start near 0.17/0.5 °E
    assert shift == 0
    assert np.median(np.abs(coarse - z60)) < 150


def test_sample_relief_hits_nodes_and_is_periodic():
    lon, lat, z = load_relief()
    np.testing.assert_allclose(sample_relief(lon[None, :], lat[:, None]), z)
    # Across the seam: 359.9 °E equals -0.1 °E, and midway between the last and first columns is their mean.
    np.testing.assert_allclose(sample_relief(359.9, 10.3), sample_relief(-0.1, 10.3))
    mid = sample_relief(0.0, lat[50])
    np.testing.assert_allclose(mid, 0.5 * (z[50, -1] + z[50, 0]))
    # Bilinear: exact for a field linear in the index, so for a synthetic relief.
    synth = (lon, lat, lat[:, None] * 10.0 + 0 * lon[None, :])
    np.testing.assert_allclose(sample_relief([12.3, 200.0], [33.3, -44.4], synth), [333.0, -444.0])
    # Poles: held constant, finite.
    assert np.isfinite(sample_relief([0, 90], [90.0, -90.0])).all()


def test_load_etopo_errors(tmp_path):
    with pytest.raises(DataError, match="not found"):
        load_etopo(tmp_path / "missing.cdf")
    bad = tmp_path / "bad.cdf"
    bad.write_bytes(b"not netcdf at all")
    with pytest.raises(DataError, match="bad.cdf"):
        load_etopo(bad)
