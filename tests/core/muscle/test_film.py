"""Film placements: counts, positions inside the box, bound heads touching actin, tasks and planner."""

import numpy as np
import pytest

from nephele.core.errors import DataError
from nephele.core.muscle import film
from nephele.core.pipeline import tasks


@pytest.fixture(scope="module")
def sim():
    return film.simulate(film.film_params(frames=6, seed=4))


def test_counts_and_box(sim):
    cell, frames = sim
    assert len(frames) == 6
    mol = film.frame_molecules(cell, frames[-1])
    n_actin = 2 * 468 * 4
    assert len(mol.blobs) == n_actin + 2 * 270 * 7
    assert np.all(mol.blobs.part[:n_actin // 2] == film.ACTIN)
    c = mol.blobs.centers
    assert np.all(c >= 0) and np.all(c < mol.box)
    assert len(mol.cylinders.starts) == 2 * (135 + 3)
    np.testing.assert_allclose(mol.box, cell.box)


def test_bound_heads_touch_their_actin(sim):
    cell, frames = sim
    f = frames[-1]
    assert (f.sites >= 0).any()
    mol = film.frame_molecules(cell, f)
    # Motor ellipsoids of a bound head lie within a few nm of some actin ellipsoid (their blobs blend).
    n_actin = 468 * 4
    actin = mol.blobs.centers[:n_actin]
    head = mol.blobs.centers[n_actin:n_actin + 270 * 7].reshape(270, 7, 3)
    bound = np.flatnonzero(f.sites >= 0)
    # Distance from each bound head's upper-50K ellipsoid (the actin-binding end) to the nearest
    # ellipsoid of the subunit it is bound to, against the same for the subunit 13 further (one crossover on).
    sub = actin.reshape(-1, 4, 3)

    def gap(idx, site):
        tips = head[idx, -2]
        return np.linalg.norm(cell.min_image(tips[:, None] - sub[site]), axis=2).min(axis=1)

    own = gap(bound, f.sites[bound])
    far = gap(bound, (f.sites[bound] // 78) * 78 + (f.sites[bound] % 78 + 13) % 78)

    assert own.max() < 12.0  # contact ~5 nm plus the tip spring's thermal spread (kT/k = 8 nm^2)
    assert np.all(far > own)


def test_early_frames_do_not_wait_for_the_film():
    # frame k depends only on the steps before it: simulated up to it, extended later, or whole
    p = film.film_params(frames=5, seed=11)
    film._SIMS.clear()
    _, first2 = film.simulate(p, upto=2)
    _, first4 = film.simulate(p, upto=4)  # the same simulation carried on
    assert len(first2) == 2 and len(first4) == 4 and film.simulate(p, upto=0)[1] == []
    film._SIMS.clear()
    _, whole = film.simulate(p)
    assert len(whole) == 5 and [f.time for f in first4] == [f.time for f in whole[:4]]
    for a, b in zip(first4, whole):
        for name in ("rotations", "states", "sites", "slide", "motor"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_same_params_same_frames():
    a = film.simulate(film.film_params(frames=3, seed=9))[1][-1].rotations.copy()
    film.simulate(film.film_params(frames=3, seed=10))
    b = film.simulate(film.film_params(frames=3, seed=9))[1][-1].rotations
    np.testing.assert_array_equal(a, b)


@pytest.mark.filterwarnings("error::RuntimeWarning")  # the S1 models' sheared Gaussians once overflowed exp
def test_frame_task_meshes_molecules():
    out = tasks.run("muscle_frame", {**film.film_params(frames=1, spacing=1.0), "frame": 0})
    v = out["vertices"]
    assert len(v) > 1000 and len(out["faces"]) > 1000
    assert np.all(v >= -1e-4) and np.all(v <= out["box"] + 1e-4)
    assert set(np.unique(out["molecule"])) == {film.ACTIN, film.MOTOR_PART, film.LEVER_PART}
    assert set(np.unique(out["cyl_molecule"])) == {film.TAIL, film.BACKBONE}


def test_planner_maps_scene_frames():
    p = {"kind": "muscle", "film": {"frames": 10}, "frame_start": 1}
    (kind, tp), = tasks.plan(p, 1)
    assert kind == "muscle_frame" and tp["frame"] == 0
    assert tasks.plan(p, 500)[0][1]["frame"] == 9
    assert tasks.plan(p, -3)[0][1]["frame"] == 0


@pytest.mark.parametrize("kw", [{"frames": 0}, {"spacing": 0.0}, {"frame_time": np.nan}, {"colour": 1}])
def test_bad_film_params(kw):
    with pytest.raises(DataError):
        film.film_params(**kw)


def test_frame_out_of_range():
    with pytest.raises(DataError, match="frame"):
        film.frame_meshes(film.film_params(frames=2), 5)
