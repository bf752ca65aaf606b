"""The Windows library, cross-built here, run under wine64 on the kernels' real inputs and compared
with the Linux library's outputs (``-k wine``).

Calls are recorded on Linux while the drivers below run the Python code that calls the kernels, then
replayed by native/tests/harness.c, built against each library.  Adding a kernel: one ``KERNEL`` line
in native/tests/kernels.def; if no driver below reaches it, a driver (a small call of its Python
caller, ``DRIVERS``); if its results depend on libm (exp, log, pow...), an entry in ``TOLERANCE`` with
the rtol its NumPy-twin test uses.  Everything else is compared bit for bit.  The first two calls of
each kernel are recorded, or, where ``PATHS`` tells a kernel's paths apart, of each path.
"""

import ctypes
import re
import subprocess

import numpy as np
import pytest
from kernel_calls import Recorder, loaded, read_out, write_calls

from nephele.core import native
from nephele.core.light import scatter
from nephele.core.muscle import blobby

pytestmark = pytest.mark.slow


def _rotations(rng, n):
    q, _ = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    return q


def blobby_plain():
    """Every mesher kernel: 40 random ellipsoids, one of them 20:1 (the large-exponent node values)."""
    rng = np.random.default_rng(5)
    c, s = rng.uniform(0, 6, (40, 3)), rng.uniform(0.4, 1.0, (40, 3))
    s[0] = [4.0, 0.2, 0.2]
    blobby.blobby_surface(c, _rotations(rng, 40), s, rng.uniform(0.6, 1.4, 40), 0.3, 0.2, threads=2)


def blobby_periodic():
    """The periodic paths: images, wrapped keys, nodes lying on the box."""
    rng = np.random.default_rng(6)
    c = rng.uniform(0, 5, (25, 3))
    blobby.blobby_surface(c, _rotations(rng, 25), rng.uniform(0.4, 0.9, (25, 3)), rng.uniform(0.6, 1.4, 25), 0.3,
                          0.25, box=(5.0, 5.5, 4.5), threads=1)


def fastexp_edges():
    """fastexp.h's exp (its test's kernel) on its range ends, NaN, infinities and subnormal results."""
    fn = native.kernel("blobby_fastexp", None, [ctypes.c_int64] + [np.ctypeslib.ndpointer(np.float64, flags="C")] * 2)
    x = np.concatenate([[-np.inf, -1000.0, -708.5, -708.0, -707.9, np.nan, 0.0, -0.0, 709.0, 709.5, 1e300, np.inf],
                        np.linspace(-60, 5, 4001), np.random.default_rng(7).uniform(-708, 709, 4003)])
    fn(len(x), x, np.empty_like(x))


def _solve(sigma, size, **kw):
    """scatter.solve on one thread: the recorder finds the arrays behind a kernel's addresses in the
    calling frames, which a pool thread's stack lacks."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("OMP_NUM_THREADS", "1")
        return scatter.solve(sigma, size, **kw)


def scatter_cloud():
    """Every scatter kernel: a 10x10x8 cloud under an oblique sun and a sky, second moments (P2
    terms, scatter_profile's second half), escapes stored and read back (profile_every 2, pass 9),
    2x2 then 1x1 sub-directions per bin."""
    z, y, x = np.meshgrid(*[np.linspace(-1, 1, n) for n in (8, 10, 10)], indexing="ij")
    cloud = np.where(x * x + 1.5 * y * y + z * z < 0.7, 12.0 * (1.2 - x * x - z), 0.0)
    _solve(cloud, (1, 1, 0.8), albedo=0.99, g=0.8, sun_dir=(0.6, -0.35, 0.55), sky_radiance=0.3,
           second_moments=True, profile_every=2, tol=1e-9, extrapolate=False, max_passes=9)


def scatter_slab():
    """The periodic sides: beams wrapping, and in flat voxels (2.5:1) shifted by more than a cell per
    layer (the sun by 1.56 in x); isotropic scattering's shared profile (first moments only); then a
    warm start (signed unshot light) with sources spread evenly (no profiles)."""
    slab = np.full((8, 3, 3), 2.0)
    slab[5] = 4.0
    kw = dict(albedo=0.9, g=0.0, sun_dir=(0.5, 0.2, 0.8), periodic=(True, True, False), max_passes=4)
    prev = _solve(slab, (0.3, 0.3, 2.0), **kw)
    _solve(slab * 1.1, (0.3, 0.3, 2.0), source_profile=False, warm=prev, **kw)


def scatter_view():
    """The views' plane march (one thread, as :func:`_solve`): a cloud with holes seen from outside
    with a background, and from inside (rays starting in the cloud), one and two samples a voxel."""
    rng = np.random.default_rng(8)
    sigma = 20.0 * rng.uniform(0, 1, (6, 8, 10)) * (rng.random((6, 8, 10)) > 0.3)
    source = (rng.uniform(0, 2, sigma.shape) * (sigma > 0)).astype(np.float32)
    size = (1.0, 0.8, 0.6)
    scatter.march_planes(sigma, source, size, scatter.orbit_camera(0.7, size, width=24, height=18), background=0.5,
                         threads=1)
    inside = scatter.orbit_camera(2.0, size, distance=0.2, width=24, height=18)
    scatter.march_planes(sigma, source, size, inside, samples=2, threads=1)


DRIVERS = (blobby_plain, blobby_periodic, fastexp_edges, scatter_cloud, scatter_slab, scatter_view)


def _sweep_path(ref, bin_lo, bin_hi, work):
    s = ref._obj  # struct nph_sweep: the row's mode, its P2 term, moments, cache, sub-beams, sides
    return (s.em is None, s.kap is None, s.qa is None, s.mom is None, s.slot_m2 >= 0, s.cache_mode, s.per_sub,
            s.sign, bool(s.periodic_a or s.periodic_b))


# kernel -> the path a call takes (a function of its arguments): the first calls of each path are
# recorded, not only each kernel's first calls (scatter_sweep's are the sun's, without emission)
PATHS = {"scatter_sweep": _sweep_path,
         "scatter_moments": lambda *a: (a[9] >= 0, a[10] >= 0, a[16] is None),  # kept, second, also
         "scatter_profile": lambda *a: a[3]}  # second moments

# kernel -> (buffer dtype, rtol) where results go through libm (its float32 expf: glibc's vs the UCRT's),
# the tolerance of the kernel's NumPy-twin test (tests/core/muscle/test_blobby_native_nodes.py).
TOLERANCE = {"blobby_node_values": (np.float32, 2e-6)}


@pytest.fixture(scope="module")
def recorded(linux_lib, tmp_path_factory, monkeypatch_module):
    """The drivers' kernel calls through the freshly built Linux library, and CALLS.bin."""
    lib = loaded(linux_lib)
    monkeypatch_module.setattr(native, "_module", lambda: lib)
    rec = Recorder(native.kernel, paths=PATHS)
    monkeypatch_module.setattr(native, "kernel", rec.kernel)
    for drive in DRIVERS:
        drive()
    path = tmp_path_factory.mktemp("calls") / "calls.bin"
    write_calls(rec.calls, path)
    return rec.calls, path


@pytest.fixture(scope="module")
def monkeypatch_module():
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


def _entries(harness, cmd=(), env=None):
    out = subprocess.run([*cmd, str(harness), "--list"], capture_output=True, text=True, check=True, env=env).stdout
    return {ln.split(" ", 2)[0]: (ln.split(" ", 2)[1], tuple(ln.split(" ", 2)[2].split(", ")))
            for ln in out.splitlines() if ln.strip()}


def _linux_exports(lib):
    out = subprocess.run(["nm", "-D", "--defined-only", str(lib)], capture_output=True, text=True, check=True).stdout
    return {m.group(1) for m in re.finditer(r"(?m)^\S+ [Ti] (\w+)$", out)}


def test_wine_every_exported_kernel_has_a_harness_entry(harnesses, linux_lib, windows_lib, build, recorded):
    entries = _entries(harnesses[0])
    kernels = _linux_exports(linux_lib)
    assert kernels == set(entries), (f"kernels.def lacks {sorted(kernels - set(entries))} / "
                                     f"has extra {sorted(set(entries) - kernels)}")
    dll = set(build.describe(windows_lib)["exports"])
    assert dll == kernels, sorted(dll ^ kernels)  # no start-up code's symbols either (build.WINDOWS_LINK)
    called = {c.name for c in recorded[0]}
    assert called == kernels, f"no driver in test_wine.DRIVERS reaches {sorted(kernels - called)}"


def test_wine_entries_match_the_python_types(harnesses, recorded):
    entries = _entries(harnesses[0])
    for c in recorded[0]:
        assert entries[c.name] == (c.sig[0], c.sig[1]), (c.name, entries[c.name], c.sig)


def test_wine_linux_harness_replays_the_calls_exactly(harnesses, recorded, tmp_path):
    # The replay itself is faithful: the harness reproduces what the live calls from Python gave.
    calls, path = recorded
    subprocess.run([str(harnesses[0]), str(path), str(tmp_path / "out.bin")], check=True)
    got = read_out(tmp_path / "out.bin")
    assert len(got) == len(calls)
    for c, (result, bufs) in zip(calls, got):
        assert result == (c.result or 0), c.name
        assert [b for i, b in enumerate(bufs) if i not in c.tables] == [b for i, b in enumerate(c.after)
                                                                        if i not in c.tables], c.name


def test_wine_windows_kernels_match_linux(harnesses, recorded, wine, tmp_path):
    calls, path = recorded
    subprocess.run([str(harnesses[0]), str(path), str(tmp_path / "linux.bin")], check=True)
    cmd, env = wine
    exe = harnesses[1]
    # Relative paths from the exe's folder: wine maps the Unix working directory to a drive.
    (exe.parent / "calls.bin").write_bytes(path.read_bytes())
    res = subprocess.run([*cmd, exe.name, "calls.bin", "out.bin"], cwd=exe.parent, env=env, capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    linux, windows = read_out(tmp_path / "linux.bin"), read_out(exe.parent / "out.bin")
    assert len(windows) == len(linux) == len(calls)
    exact = close = written = 0
    for c, (r_lin, b_lin), (r_win, b_win) in zip(calls, linux, windows):
        assert r_win == r_lin, c.name
        for i, (lin, win) in enumerate(zip(b_lin, b_win, strict=True)):
            written += lin != c.before[i]  # outputs: what the call changed
            if lin == win:
                exact += 1
                continue
            assert c.name in TOLERANCE, f"{c.name}: buffer {i} differs between Windows and Linux"
            dtype, rtol = TOLERANCE[c.name]
            a, b = np.frombuffer(win, dtype).astype(float), np.frombuffer(lin, dtype).astype(float)
            assert np.all(np.abs(a - b) <= rtol * np.abs(b) + 1e-37), (c.name, i, np.abs(a - b).max())
            close += 1
    print(f"{len(calls)} calls of {len({c.name for c in calls})} kernels: {written} output buffers, {exact} of "
          f"all buffers bit-identical, {close} within tolerance")
    assert written >= len(calls)  # every call wrote something, and it was compared
