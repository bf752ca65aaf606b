"""Fuzzing every reader with hostile bytes: seeds, mutations and a guarded worker process.

A *case* is a seed (a real file, or a small folder of files such as a GrADS
``.ctl``/``.dat`` pair or a Zarr store) and a list of mutation *ops*:
truncations, bit flips, bytes and machine words set to edge values (0, -1,
2**31 - 1, ...: a header claiming 10**12 values), spans deleted or doubled,
and in text files numbers replaced by edge values.  The same ops come from a
hypothesis strategy (the test tiers, shrinking off: a case is cheap to read
from its ops) or from a seeded ``random.Random`` (``make fuzz``).

Each case runs in a worker process (:mod:`fuzz_worker`) whose data segment
is limited to 2 GiB above its idle size and whose answer must come within
10 s of its CPU time (so a loaded machine does not make hangs; 100 s of wall
time for one blocked in I/O); the worker is restarted after a hang or a crash.  Only the project's
``DataError`` may escape a reader: anything else, a hang, a crash or a
``MemoryError`` is a finding.
"""

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TIMEOUT_S = 10.0
MEMORY_LIMIT = 2 << 30
BAD = ("bug", "hang", "crash", "memory")
"""Outcomes that are findings; ``ok`` (read without error) and ``data_error`` are fine."""

# --- mutations -------------------------------------------------------------------------------------

EDGE_WORDS = {
    1: (0, 1, 0x7F, 0x80, 0xFF),
    2: (0, 1, 0x7FFF, 0x8000, 0xFFFF),
    4: (0, 1, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF, 1_000_000_000, 0x3F800000),
    8: (0, 1, (1 << 63) - 1, 1 << 63, (1 << 64) - 1, 10**12, 0x7FF8000000000000),
}
EDGE_NUMBERS = ("0", "-1", "1", "1000000000000", "99999999999999999999", "-2147483649", "nan", "inf", "-inf",
                "1e308", "1e-320", "", "x", "4294967296", "3.5")
_NUMBER = re.compile(rb"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")
HEAD = 4096
"""Most ops land in a file's first bytes, where the headers are."""


def _pos(data, where, head):
    n = len(data)
    if n == 0:
        return 0
    return where % min(n, HEAD) if head else where % n


def apply_ops(data, ops):
    """``data`` (bytes) after the mutation ``ops`` (a list of tuples, see :func:`random_ops`)."""
    b = bytearray(data)
    for op in ops:
        kind = op[0]
        if kind == "trunc":
            del b[int(len(b) * op[1]):]
        elif not b:
            continue
        elif kind == "flip":
            p = _pos(b, op[1], op[2])
            b[p] ^= 1 << op[3]
        elif kind == "byte":
            b[_pos(b, op[1], op[2])] = op[3]
        elif kind == "word":
            _, where, head, width, value, order = op
            p = _pos(b, where, head)
            b[p:p + width] = value.to_bytes(width, order)
        elif kind == "del":
            p = _pos(b, op[1], op[2])
            del b[p:p + op[3]]
        elif kind == "dup":
            p = _pos(b, op[1], op[2])
            b[p:p] = b[p:p + op[3]]
        elif kind == "num":
            found = list(_NUMBER.finditer(b))
            if found:
                m = found[op[1] % len(found)]
                b[m.start():m.end()] = op[2].encode()
        else:
            raise ValueError(f"unknown op {op!r}")
    return bytes(b)


def random_ops(rng, text=False):
    """1-4 random ops, as :func:`ops_strategy` draws them."""
    ops = []
    for _ in range(rng.choice((1, 1, 2, 3, 4))):
        kind = rng.choice(("num", "num", "num", "trunc", "flip", "del", "dup") if text else
                          ("trunc", "flip", "flip", "byte", "word", "word", "del", "dup"))
        where, head = rng.randrange(1 << 31), rng.random() < 0.7
        if kind == "trunc":
            ops.append(("trunc", rng.random()))
        elif kind == "flip":
            ops.append(("flip", where, head, rng.randrange(8)))
        elif kind == "byte":
            ops.append(("byte", where, head, rng.randrange(256)))
        elif kind == "word":
            width = rng.choice((1, 2, 4, 8))
            ops.append(("word", where, head, width, rng.choice(EDGE_WORDS[width]), rng.choice(("big", "little"))))
        elif kind in ("del", "dup"):
            ops.append((kind, where, head, rng.choice((1, 2, 4, 8, 64, 512))))
        else:
            ops.append(("num", rng.randrange(1 << 16), rng.choice(EDGE_NUMBERS)))
    return ops


def ops_strategy(text=False):
    """A hypothesis strategy of op lists (the same shapes as :func:`random_ops`)."""
    from hypothesis import strategies as st

    where, head = st.integers(0, (1 << 31) - 1), st.booleans()
    width = st.sampled_from((1, 2, 4, 8))
    word = width.flatmap(lambda w: st.tuples(st.just("word"), where, head, st.just(w), st.sampled_from(EDGE_WORDS[w]),
                                             st.sampled_from(("big", "little"))))
    span = st.sampled_from((1, 2, 4, 8, 64, 512))
    binary = [st.tuples(st.just("trunc"), st.floats(0, 1)), st.tuples(st.just("flip"), where, head, st.integers(0, 7)),
              st.tuples(st.just("byte"), where, head, st.integers(0, 255)), word,
              st.tuples(st.just("del"), where, head, span), st.tuples(st.just("dup"), where, head, span)]
    texty = [st.tuples(st.just("num"), st.integers(0, 1 << 16), st.sampled_from(EDGE_NUMBERS)), *binary[:2],
             *binary[4:]]
    return st.lists(st.one_of(texty if text else binary), min_size=1, max_size=4)


# --- seeds ---------------------------------------------------------------------------------------


@dataclass
class Seed:
    """A reader's input: ``files`` (relative name -> bytes) in a folder, the ``entry`` handed to the reader,
    the ``mutable`` files and which of those are text."""

    target: str
    name: str
    files: dict
    entry: str
    mutable: tuple
    text: tuple = ()

    def write(self, folder, mutated=None, ops=None):
        """Write the seed into ``folder`` with ``ops`` applied to file ``mutated``; the entry's path."""
        folder = Path(folder)
        for rel, data in self.files.items():
            p = folder / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(apply_ops(data, ops) if rel == mutated and ops else data)
        return folder / self.entry


def _single(target, path, text=False):
    path = Path(path)
    return Seed(target, path.name, {path.name: path.read_bytes()}, path.name, (path.name,),
                (path.name,) if text else ())


def grib_seed():
    """A small GRIB2 file with 3-D fields (t, r, u, v on 5 pressure levels), made with ecCodes."""
    import eccodes
    import numpy as np

    out = bytearray()
    for number, (cat, num) in enumerate(((0, 0), (1, 1), (2, 2), (2, 3))):
        for level in (1000, 850, 700, 500, 300):
            h = eccodes.codes_grib_new_from_samples("regular_ll_pl_grib2")
            try:
                eccodes.codes_set_key_vals(h, {
                    "Ni": 36, "Nj": 19, "latitudeOfFirstGridPointInDegrees": 90,
                    "longitudeOfFirstGridPointInDegrees": 0,
                    "latitudeOfLastGridPointInDegrees": -90, "longitudeOfLastGridPointInDegrees": 350,
                    "iDirectionIncrementInDegrees": 10, "jDirectionIncrementInDegrees": 10,
                    "typeOfFirstFixedSurface": 100,
                    "level": level, "discipline": 0, "parameterCategory": cat, "parameterNumber": num,
                    "dataDate": 20240101, "dataTime": 0})
                eccodes.codes_set(h, "bitsPerValue", 12)
                eccodes.codes_set_values(h, np.linspace(0.0, 1.0, 36 * 19) * (number + 1) + level / 1000.0)
                out += eccodes.codes_get_message(h)
            finally:
                eccodes.codes_release(h)
    return bytes(out)


def small_vtu(fire):
    """A 3x3x3-cell corner of the fire's grid as VTK writes it (appended base64, zlib blocks, UInt32 headers):
    the same layout as ``fire_ug.vtu`` at a 200th of its size, so a case costs milliseconds, not seconds."""
    import base64
    import zlib

    import numpy as np

    from nephele.core.flowvol.unstructured import read_vtu

    g = read_vtu(fire)
    n = 4
    pts = np.stack(np.meshgrid(*[np.linspace(0, 1, n)] * 3, indexing="ij"), -1).reshape(-1, 3)[:, ::-1].copy()
    idx = np.arange(n ** 3).reshape(n, n, n)
    cells = np.array([[idx[k, j, i], idx[k, j, i + 1], idx[k, j + 1, i + 1], idx[k, j + 1, i], idx[k + 1, j, i],
                       idx[k + 1, j, i + 1], idx[k + 1, j + 1, i + 1], idx[k + 1, j + 1, i]]
                      for k in range(n - 1) for j in range(n - 1) for i in range(n - 1)])
    arrays = [("Float32", "uvw", 3, g["point_data"]["uvw"][: n ** 3].astype("<f4")),
              ("Float32", None, 3, pts.astype("<f4")), ("Int32", "connectivity", 1, cells.astype("<i4")),
              ("Int32", "offsets", 1, 8 * np.arange(1, len(cells) + 1, dtype="<i4")),
              ("UInt8", "types", 1, np.full(len(cells), 12, "u1"))]
    blob, tags, offset = b"", [], 0
    for kind, name, comps, a in arrays:
        raw = a.tobytes()
        packed = zlib.compress(raw)
        block = base64.b64encode(np.array([1, len(raw), len(raw), len(packed)],
                                          "<u4").tobytes()) + base64.b64encode(packed)
        attr = f' Name="{name}"' if name else ""
        tags.append(f'<DataArray type="{kind}"{attr} NumberOfComponents="{comps}" format="appended" '
                    f'offset="{offset}"/>')
        blob += block
        offset += len(block)
    xml = (f'<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian" '
           f'compressor="vtkZLibDataCompressor">\n<UnstructuredGrid><Piece NumberOfPoints="{n ** 3}" '
           f'NumberOfCells="{len(cells)}">\n'
           f"<PointData>{tags[0]}</PointData>\n<Points>{tags[1]}</Points>\n<Cells>{''.join(tags[2:])}</Cells>\n"
           f'</Piece></UnstructuredGrid>\n<AppendedData encoding="base64">\n_')
    return xml.encode() + blob + b"\n</AppendedData>\n</VTKFile>\n"


def zarr_files(nc_path, folder):
    """The files of a Zarr store written by xarray from the NetCDF file ``nc_path``."""
    import xarray as xr

    store = Path(folder) / "seed.zarr"
    with xr.open_dataset(nc_path, decode_times=False) as ds:
        ds.to_zarr(store, mode="w")
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(store.rglob("*")) if p.is_file()}


def build_seeds(data_dirs, work):
    """Every reader's seeds from ``data_dirs`` (tests/data and the shared data folder, when there)."""
    import importlib.util

    files = {}
    for d in data_dirs:
        for p in sorted(Path(d).rglob("*")):
            if p.is_file():
                files.setdefault(p.name, p)
    seeds = []
    for name, p in files.items():
        if p.suffix == ".nc":
            seeds.append(_single("netcdf", p))
        elif p.suffix in (".grib2", ".grib"):
            seeds.append(_single("grib", p))
        elif p.suffix == ".cdf":
            seeds.append(_single("relief", p))
        elif p.suffix == ".pqr" and p.stat().st_size < 500_000:
            seeds.append(_single("pqr", p, text=True))
            lines = p.read_bytes().splitlines(keepends=True)  # its first 300 atoms: cheap cases, same records
            seeds.append(Seed("pqr", f"{p.stem}_300.pqr", {"small.pqr": b"".join(lines[:300])}, "small.pqr",
                              ("small.pqr",), ("small.pqr",)))
        elif p.suffix == ".vtu":
            seeds.append(_single("vtu", p, text=True))
            seeds.append(Seed("vtu", "fire_corner.vtu", {"small.vtu": small_vtu(p)}, "small.vtu", ("small.vtu",),
                              ("small.vtu",)))
        elif p.suffix == ".ctl" and p.with_suffix(".dat").is_file():
            seeds.append(Seed("grads", name,
                              {name: p.read_bytes(), p.with_suffix(".dat").name: p.with_suffix(".dat").read_bytes()},
                              name, (name, p.with_suffix(".dat").name), (name,)))
    if importlib.util.find_spec("cfgrib") and importlib.util.find_spec("eccodes"):
        seeds.append(Seed("grib", "isobaric.grib2", {"isobaric.grib2": grib_seed()}, "isobaric.grib2",
                          ("isobaric.grib2",)))
    if importlib.util.find_spec("zarr") and "cam_vinth2p.nc" in files:
        try:
            z = zarr_files(files["cam_vinth2p.nc"], work)
        except Exception:  # noqa: BLE001 - an xarray too old for this zarr (Python 3.11's pins): no Zarr seed
            z = None
        if z:
            meta = tuple(k for k in z if k.endswith((".json", ".zarray", ".zattrs", ".zgroup", ".zmetadata")))
            seeds.append(Seed("zarr", "cam_vinth2p.zarr", z, "seed.zarr", tuple(z), meta))
    return seeds


def cases(seeds, rng):
    """Endless ``(seed, mutated file, ops)`` from ``rng``, round robin over the readers."""
    by_target = {}
    for s in seeds:
        by_target.setdefault(s.target, []).append(s)
    targets = sorted(by_target)
    i = 0
    while True:
        mine = by_target[targets[i % len(targets)]]
        # Smaller seeds more often (a case costs about its size), every seed now and then.
        seed = rng.choices(mine, weights=[sum(map(len, m.files.values())) ** -0.5 for m in mine])[0]
        i += 1
        # A store's metadata and a data file's header matter more than its bulk.
        pick = seed.text if seed.text and rng.random() < 0.7 else seed.mutable
        mutated = rng.choice(pick)
        yield seed, mutated, random_ops(rng, text=mutated in seed.text)


# --- the guarded worker ------------------------------------------------------------------------


class Runner:
    """Runs cases in a worker process with a memory limit and a timeout; restarts it when it dies or hangs."""

    def __init__(self, timeout=TIMEOUT_S, memory=MEMORY_LIMIT, recycle=2000):
        self.timeout, self.memory, self.recycle = timeout, memory, recycle
        self.proc = None
        self.count = 0
        self.work = Path(tempfile.mkdtemp(prefix="nephele-fuzz-",
                                          dir="/dev/shm" if os.path.isdir("/dev/shm") else None))

    def _start(self):
        # The worker imports nephele (and the readers' libraries) exactly as this process does.
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
        self.proc = subprocess.Popen([sys.executable, str(HERE / "fuzz_worker.py"), str(self.memory)],
                                     stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env, text=True, bufsize=1)
        ready = self._answer(120.0)  # imports (xarray, netCDF4, cfgrib) take a few seconds
        if ready is None or ready.get("status") != "ready":
            raise RuntimeError(f"the fuzz worker did not start: {ready}")
        self.count = 0

    def _cpu(self):
        """CPU seconds the worker has used (Linux), or None: a case is timed by its own work, not by the load."""
        try:
            with open(f"/proc/{self.proc.pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return None

    def _answer(self, timeout):
        """The worker's next line; None when it used ``timeout`` CPU seconds (or ten times that in wall time) first."""
        import selectors
        import time

        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        cpu0, wall0 = self._cpu(), time.monotonic()
        try:
            while not sel.select(0.25):
                cpu = self._cpu()
                used = cpu - cpu0 if cpu is not None and cpu0 is not None else time.monotonic() - wall0
                if used > timeout or time.monotonic() - wall0 > 10 * timeout:
                    return None
            line = self.proc.stdout.readline()
        finally:
            sel.close()
        return json.loads(line) if line else {"status": "crash", "detail": f"worker exited with {self.proc.wait()}"}

    def stop(self):
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None

    def close(self):
        self.stop()
        shutil.rmtree(self.work, ignore_errors=True)

    def run(self, seed, mutated=None, ops=None):
        """Outcome of one case: ``{"status": "ok" | "data_error" | "bug" | "memory" | "hang" | "crash", ...}``."""
        if self.proc is None or self.proc.poll() is not None or self.count >= self.recycle:
            self.stop()
            self._start()
        folder = self.work / f"case{self.count}"
        entry = seed.write(folder, mutated, ops)
        self.count += 1
        try:
            self.proc.stdin.write(json.dumps({"target": seed.target, "path": str(entry)}) + "\n")
            self.proc.stdin.flush()
            out = self._answer(self.timeout)
        except BrokenPipeError:
            out = {"status": "crash", "detail": f"worker exited with {self.proc.wait()}"}
        if out is None:
            out = {"status": "hang", "detail": f"no answer within {self.timeout:g} CPU seconds"}
        if out["status"] in ("hang", "crash") or out.get("restart"):
            self.stop()
        shutil.rmtree(folder, ignore_errors=True)
        return out


def describe(seed, mutated, ops, out):
    return (f"{out['status']}: {seed.target} {seed.name} [{mutated}] ops={ops!r}\n  {out.get('detail', '')}")
