"""One test per class of bug the readers' fuzzing found: each failed (a foreign error type, a crash,
a hang or a huge allocation) before its fix and gives one DataError line now."""

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from nephele.core.errors import DataError

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
sys.path.insert(0, str(Path(__file__).resolve().parent))


def one_line(exc_info, *words):
    text = str(exc_info.value)
    assert "\n" not in text and all(w in text for w in words), text
    return text


# --- GRIB --------------------------------------------------------------------------------------


def _grib2(tmp_path):
    pytest.importorskip("cfgrib")
    pytest.importorskip("eccodes")
    from fuzzlib import grib_seed

    return grib_seed()


def _open_in_child(path):
    """``open_dataset(path)`` in a child process (a crash there, SIGSEGV, is what the bug was: no
    pytest.raises can catch it); its output, after checking it exited normally."""
    code = textwrap.dedent(f"""
        from nephele.core.climate import open_dataset
        from nephele.core.errors import DataError
        try:
            open_dataset({str(path)!r})
        except DataError as exc:
            print("DataError:", exc)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out


def test_grib_section_claiming_more_than_its_message_is_refused_before_ecCodes(tmp_path):
    """Fuzz: a section 3 length of 3.9e9 in a 1205-byte message made cfgrib segfault the process."""
    data = bytearray(_grib2(tmp_path))
    sec3 = 16 + int.from_bytes(data[16:20], "big")  # after sections 0 and 1
    assert data[sec3 + 4] == 3
    data[sec3:sec3 + 4] = (3_892_314_149).to_bytes(4, "big")
    path = tmp_path / "bad.grib2"
    path.write_bytes(bytes(data))
    out = _open_in_child(path)
    assert "DataError:" in out.stdout and "section 3" in out.stdout and "claims 3892314149 bytes" in out.stdout


def _grib1():
    """A real GRIB1 file's bytes and the offset of its first message's GDS (after section 0 and the PDS)."""
    pytest.importorskip("eccodes")
    data = bytearray((DATA / "grib" / "t_on_different_level_types.grib").read_bytes())
    return data, 8 + int.from_bytes(data[8:11], "big")


def test_grib1_section_claiming_more_than_its_message_is_refused_before_ecCodes(tmp_path):
    """Fuzz (make fuzz N=20000, seed 1795913527): one bit flipped in a GRIB1 GDS length (32 -> 8388640 bytes)
    made ecCodes segfault reading the grid section's md5; GRIB1 sections were not walked."""
    data, gds = _grib1()
    assert data[7] == 1 and data[15] & 0x80 and int.from_bytes(data[gds:gds + 3], "big") == 32
    data[gds] ^= 0x80
    path = tmp_path / "bad.grib"
    path.write_bytes(bytes(data))
    out = _open_in_child(path)
    assert "DataError:" in out.stdout and "its GDS at byte 60 claims 8388640 bytes" in out.stdout, out.stdout


def test_grib1_grid_claiming_billions_of_points_is_refused_before_allocating(tmp_path):
    data, gds = _grib1()
    data[gds + 6:gds + 10] = (65000).to_bytes(2, "big") + (65000).to_bytes(2, "big")  # Ni, Nj
    path = tmp_path / "huge.grib"
    path.write_bytes(bytes(data))
    from nephele.core.climate import open_dataset

    with pytest.raises(DataError) as err:
        open_dataset(path)
    one_line(err, "huge.grib", "4,225,000,000 points", "memory")


def test_grib_grid_claiming_billions_of_points_is_refused_before_allocating(tmp_path):
    data = bytearray(_grib2(tmp_path))
    sec3 = 16 + int.from_bytes(data[16:20], "big")
    data[sec3 + 6:sec3 + 10] = (4_000_000_000).to_bytes(4, "big")  # numberOfDataPoints
    path = tmp_path / "huge.grib2"
    path.write_bytes(bytes(data))
    from nephele.core.climate import open_dataset

    with pytest.raises(DataError) as err:
        open_dataset(path)
    one_line(err, "huge.grib2", "4,000,000,000 points", "memory")


def test_grib_packing_claiming_two_billion_values_is_refused_before_allocating(tmp_path):
    """Fuzz (long run): section 5's number of packed values flipped to 2,147,484,332 made ecCodes ask numpy for
    16 GiB (MemoryError) although the grid has 684 points."""
    data = bytearray(_grib2(tmp_path))
    pos = 16
    while data[pos + 4] != 5:  # walk to section 5
        pos += int.from_bytes(data[pos:pos + 4], "big")
    assert int.from_bytes(data[pos + 5:pos + 9], "big") == 684
    data[pos + 5:pos + 9] = (2_147_484_332).to_bytes(4, "big")
    path = tmp_path / "values.grib2"
    path.write_bytes(bytes(data))
    from nephele.core.climate import open_dataset

    with pytest.raises(DataError) as err:
        open_dataset(path)
    one_line(err, "values.grib2", "2,147,484,332 points", "memory")


def test_whole_grib_messages_pass_the_walk(tmp_path):
    from nephele.core.climate.gribcheck import check_grib

    path = tmp_path / "ok.grib2"
    path.write_bytes(b"junk before" + _grib2(tmp_path))  # ecCodes skips bytes between messages, so does the walk
    assert check_grib(path) == 20
    assert check_grib(DATA / "polar_stereo.grib2") >= 1
    path.write_bytes(_grib2(tmp_path)[:-3])  # the last message cut short: left to the reader, which skips it
    assert check_grib(path) == 19


def test_a_read_failing_in_the_library_is_a_data_error(tmp_path, monkeypatch):
    """Fuzz: ecCodes' DecodingError (and netCDF4's 'RuntimeError: NetCDF: HDF error') escaped Dataset.read."""
    from nephele.core.climate import open_dataset
    from nephele.core.climate.netcdf import NetCDFDataset

    ds = open_dataset(DATA / "cam_vinth2p.nc")

    def broken(self, name, t):
        raise RuntimeError("NetCDF: HDF error")

    monkeypatch.setattr(NetCDFDataset, "_raw", broken)
    with pytest.raises(DataError) as err:
        ds.read("temperature", 0)
    one_line(err, "cam_vinth2p.nc", "field 'temperature'", "cannot read step 0", "RuntimeError: NetCDF: HDF error")


def test_netcdf_failing_while_opening_is_a_data_error(tmp_path, monkeypatch):
    """The issue's first finding: 'RuntimeError: NetCDF: HDF error' out of open_dataset (raised after the file
    opened)."""
    from nephele.core.climate import netcdf, open_dataset

    real = netcdf._find_time

    def hdf_error(ds):
        real(ds)
        raise RuntimeError("NetCDF: HDF error")

    monkeypatch.setattr(netcdf, "_find_time", hdf_error)
    with pytest.raises(DataError) as err:
        open_dataset(DATA / "cam_vinth2p.nc")
    one_line(err, "cam_vinth2p.nc", "cannot read as NetCDF (RuntimeError: NetCDF: HDF error)")


def test_netcdf4_with_a_damaged_hdf5_header_is_one_line(tmp_path):
    data = bytearray((DATA / "ncl_nc4uvt_T.nc").read_bytes())
    data[1140] ^= 16  # found by flipping header bits: "NetCDF: HDF error"
    path = tmp_path / "hdf.nc"
    path.write_bytes(bytes(data))
    from nephele.core.climate import open_dataset

    with pytest.raises(DataError) as err:
        open_dataset(path)
    one_line(err, "hdf.nc", "cannot open as NetCDF")


# --- GrADS -------------------------------------------------------------------------------------


def _ctl(tmp_path, xdef="72 linear 0 5", vars_line="1"):
    (tmp_path / "m.dat").write_bytes(np.zeros(72 * 46 * 2, "<f4").tobytes())
    (tmp_path / "m.ctl").write_text(f"dset ^m.dat\nundef -9.99e8\nxdef {xdef}\nydef 46 linear -90 4\n"
                                    f"zdef 2 levels 1000 500\ntdef 1 linear 00z01jan1987 1dy\nvars {vars_line}\nT 2 "
                                    "99 t\nendvars\n")
    return tmp_path / "m.ctl"


def test_grads_axis_claiming_1e12_values_is_refused_before_allocating(tmp_path):
    """Fuzz: 'xdef 1000000000000 linear' asked numpy for 7.3 TiB (MemoryError)."""
    from nephele.core.climate import open_dataset

    assert open_dataset(_ctl(tmp_path)).grid.shape == (2, 46, 72)
    with pytest.raises(DataError) as err:
        open_dataset(_ctl(tmp_path, xdef="1000000000000 linear 0 5"))
    one_line(err, "m.ctl", "field 'xdef'", "claims 1000000000000 values")


def test_grads_counts_that_are_not_numbers(tmp_path):
    """Fuzz: 'vars -inf' raised ValueError from int()."""
    from nephele.core.climate import open_dataset

    with pytest.raises(DataError) as err:
        open_dataset(_ctl(tmp_path, vars_line="-inf"))
    one_line(err, "m.ctl", "field 'vars'", "whole number")


# --- ETOPO relief (NetCDF 3 through scipy) -----------------------------------------------------


def _etopo(shared_data):
    return bytearray((shared_data / "terrain" / "etopo60.cdf").read_bytes())


def test_relief_header_claiming_a_huge_array_is_not_read(shared_data, tmp_path):
    """Fuzz: a dimension length of 1.3e9 made scipy read (allocate) that many bytes: MemoryError under 2 GiB."""
    from nephele.core.climate.relief import load_etopo

    data = _etopo(shared_data)
    # The first dimension's length, right after its name (padded to 4 bytes).
    name_len = int.from_bytes(data[16:20], "big")
    at = 20 + -(-name_len // 4) * 4
    data[at:at + 4] = (1_275_069_497).to_bytes(4, "big")
    path = tmp_path / "huge.cdf"
    path.write_bytes(bytes(data))
    with pytest.raises(DataError) as err:
        load_etopo(path)
    one_line(err, "huge.cdf", "not a NetCDF 3 relief file")


@pytest.mark.parametrize("cut", [30, 200, 5000])
def test_relief_cut_short_is_one_line(shared_data, tmp_path, cut):
    """Fuzz: truncated headers raised IndexError / KeyError out of scipy."""
    from nephele.core.climate.relief import load_etopo

    path = tmp_path / "cut.cdf"
    path.write_bytes(bytes(_etopo(shared_data)[:cut]))
    with pytest.raises(DataError) as err:
        load_etopo(path)
    one_line(err, "cut.cdf")


# --- PQR ---------------------------------------------------------------------------------------


def test_pqr_with_bytes_that_are_not_utf8(tmp_path):
    """Fuzz: a flipped high bit raised UnicodeDecodeError."""
    from nephele.core.muscle.molecules import read_pqr

    line = "ATOM      1  N   ASP     1      25.390  20.780  -7.680 -0.3000 1.8240\n"
    path = tmp_path / "m.pqr"
    path.write_bytes(b"REMARK caf\xe9\n" + line.encode())
    assert len(read_pqr(path).xyz) == 1
    path.write_bytes(line.replace("20.780", "20.7\xb80").encode("latin-1"))
    with pytest.raises(DataError) as err:
        read_pqr(path)
    one_line(err, "m.pqr", "line 1")


# --- VTK .vtu ----------------------------------------------------------------------------------

HEX = """<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">
 <UnstructuredGrid><Piece NumberOfPoints="{n}" NumberOfCells="{cells}">
  <PointData><DataArray type="Float32" Name="uvw" NumberOfComponents="3" format="ascii">{uvw}</DataArray></PointData>
  <Points><DataArray type="Float32" NumberOfComponents="3" format="ascii">{points}</DataArray></Points>
  <Cells><DataArray type="Int32" Name="connectivity" format="ascii">{conn}</DataArray>
   <DataArray type="Int32" Name="offsets" format="ascii">{offsets}</DataArray>
   <DataArray type="UInt8" Name="types" format="ascii">{types}</DataArray></Cells>
 </Piece></UnstructuredGrid></VTKFile>
"""
UNIT = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)


def _hex(tmp_path, cells=1, stray=None, conn=None):
    """``cells`` unit cubes in a row; ``stray``: a value for the last point's z."""
    points = np.concatenate([UNIT + [i, 0, 0] for i in range(cells)])
    if stray is not None:
        points[-1, 2] = stray
    conn = " ".join(map(str, range(8 * cells))) if conn is None else conn
    path = tmp_path / "hex.vtu"
    path.write_text(HEX.format(n=len(points), cells=cells, uvw=" ".join(["0 0 1"] * len(points)),
                               points=" ".join(f"{v:g}" for v in points.ravel()), conn=conn,
                               offsets=" ".join(str(8 * (i + 1)) for i in range(cells)),
                               types=" ".join(["12"] * cells)))
    return path


def test_vtu_corner_index_outside_the_points(tmp_path):
    from nephele.core.flowvol.unstructured import UnstructuredVelocity

    v = UnstructuredVelocity(_hex(tmp_path))
    np.testing.assert_allclose(v(np.array([[0.5, 0.5, 0.5]])), [[0.0, 0.0, 1.0]])
    with pytest.raises(DataError) as err:
        UnstructuredVelocity(_hex(tmp_path, conn="0 1 2 3 4 5 6 99"))
    one_line(err, "hex.vtu", "do not fit together")
    with pytest.raises(DataError) as err:
        UnstructuredVelocity(_hex(tmp_path, conn="0 1 2 3 4 5 6"))
    one_line(err, "hex.vtu", "7 corner indices for 1 hexahedra")


def test_vtu_stray_point_is_refused_before_a_huge_bucket_grid(tmp_path):
    """Fuzz: one coordinate set to 1e30 sized the cell locator's buckets by it (an array of ~1e90 entries)."""
    from nephele.core.flowvol.unstructured import UnstructuredVelocity

    assert UnstructuredVelocity(_hex(tmp_path, cells=3)).cell_size == 1.0
    with pytest.raises(DataError) as err:
        UnstructuredVelocity(_hex(tmp_path, cells=3, stray=1e30))
    one_line(err, "hex.vtu", "memory", "stray point")


@pytest.mark.parametrize("damage", ["cut", "offset", "zlib", "header"])
def test_vtu_damaged_appended_data(shared_data, tmp_path, damage):
    """Fuzz: a file cut short (ValueError 'subsection not found'), a misaligned offset (binascii.Error),
    damaged zlib blocks (zlib.error) and a block header of the wrong size (ValueError from numpy)."""
    from nephele.core.flowvol.unstructured import UnstructuredVelocity

    text = (shared_data / "flow" / "fire_ug.vtu").read_bytes()
    start = text.index(b"_", text.index(b"<AppendedData")) + 1
    if damage == "cut":
        text = text[:len(text) // 2]
    elif damage == "offset":
        text = text.replace(b'offset="39276"', b'offset="39277"')
    elif damage == "zlib":
        text = text[:start + 200] + b"AAAA" + text[start + 204:]
    else:
        text = text[:start] + text[start + 3:]
    path = tmp_path / "fire.vtu"
    path.write_bytes(text)
    with pytest.raises(DataError) as err:
        UnstructuredVelocity(path)
    one_line(err, "fire.vtu")


def test_netcdf4_header_that_makes_hdf5_loop_forever_is_refused_in_seconds(tmp_path):
    """Fuzz (long run): one byte of an HDF5 header (3479: 8 -> 50) made nc_open loop without end (> 150 s,
    no error).  Now: one DataError line after the header watchdog's 8 s.  In a child process, whose
    stuck reading thread ends with it."""
    data = bytearray((DATA / "toa_brightness_stereographic.nc").read_bytes())
    assert data[3479] == 8
    data[3479] = 50
    path = tmp_path / "loop.nc"
    path.write_bytes(bytes(data))
    code = textwrap.dedent(f"""
        import time
        from nephele.core.climate import open_dataset
        from nephele.core.errors import DataError
        t = time.perf_counter()
        try:
            open_dataset({str(path)!r})
        except DataError as exc:
            print("DataError:", exc)
        print("seconds", round(time.perf_counter() - t, 1))
    """)
    # (the library call and the CLI wait out their 8 s side by side)
    lib = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    cli = subprocess.Popen([sys.executable, "-m", "nephele.farm.cli", "info", str(path)], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    out, err = lib.communicate(timeout=300)
    assert lib.returncode == 1, err[-2000:]  # not -11 (SIGSEGV at exit)
    assert f"DataError: {path}: the HDF5 library did not finish reading the file's header in 8 s" in out
    from nephele.core.climate.hdf5check import check_header

    check_header(DATA / "ncl_nc4uvt_T.nc")  # a whole NetCDF-4 header: at once
    check_header(DATA / "cam_vinth2p.nc")  # NetCDF 3: not HDF5, not probed
    err = cli.communicate(timeout=300)[1]
    assert cli.returncode == 2 and err.strip().splitlines()[-1].startswith(f"nephele info: error: {path}: the HDF5")


def test_netcdf3_header_claiming_67_million_dimensions_is_refused_in_python(shared_data, tmp_path):
    """Fuzz (long run): a dimension count flipped to 0x04000003 made netCDF-C allocate gigabytes and, under
    the fuzz worker's 2 GiB limit, crash (SIGSEGV).  The header is now walked in Python first."""
    data = bytearray((shared_data / "climate" / "orog_mod1_rectilinear_grid_2D.nc").read_bytes())
    assert data[:4] == b"CDF\x01" and data[8:12] == b"\x00\x00\x00\x0a"  # NC_DIMENSION list
    data[12] |= 0x04
    path = tmp_path / "dims.nc"
    path.write_bytes(bytes(data))
    code = textwrap.dedent(f"""
        import resource
        from nephele.core.climate import open_dataset
        from nephele.core.errors import DataError
        with open("/proc/self/status") as f:
            used = next(int(ln.split()[1]) * 1024 for ln in f if ln.startswith("VmData:"))
        resource.setrlimit(resource.RLIMIT_DATA, (used + (2 << 30), resource.RLIM_INFINITY))
        try:
            open_dataset({str(path)!r})
        except DataError as exc:
            print("DataError:", exc)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert f"DataError: {path}: cannot open as NetCDF (damaged NetCDF 3 header" in out.stdout
    from nephele.core.climate.hdf5check import check_classic

    check_classic(shared_data / "climate" / "rectilinear_grid_3D.nc")  # a whole header passes
