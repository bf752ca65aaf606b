"""Fetch the real GRIB sample files the reader tests use, into ``build/grib-samples`` (not committed).

Operational products as their producers wrote them, shipped in two packages on PyPI
(fetched with pip, verified by their sha256, extracted file by file):

* pygrib 2.1.8 sdist (MIT), ``sampledata/``: NCEP GFS 2.5 degree forecast
  ``gfs.t12z.pgrbf120.2p5deg.grib2`` (isobaric and 30 other level types, multi-field
  u/v messages), ``rap.wrfnat.grib2`` (NCEP RAP native level, rotated grid template
  3.32769), ``rotated_ll.grib1`` (ECMWF rotated latitude/longitude), ``eta.grb`` (NCEP
  Eta on a Lambert conformal grid, 19 pressure levels);
* cfgrib 0.9.15.1 sdist (Apache-2.0), ``tests/sample-data/``: ERA5 ensemble on pressure
  levels ``era5-levels-members.grib`` (10 members x 4 times x 2 levels of z and t),
  ``regular_gg_ml_g2.grib`` (IFS model levels with pv), ``era5-levels-corrupted.grib``.

Derived here (deterministic, from the files above): ``gfs.t12z.pgrbf120.2p5deg.grib1``,
the GFS forecast re-encoded in GRIB1 by ecCodes (simple packing; ``clwmr`` and ``o3mr``,
which ecCodes cannot convert, re-labelled with NCEP's GRIB1 table 2 numbers 153 and 154).

    python tests/data/fetch_grib_samples.py [FOLDER]

``ensure()`` does the same for the tests and returns the folder; the folder can be set
with ``NEPHELE_GRIB_SAMPLES``.  Needs network access to PyPI once.
"""

import hashlib
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DEFAULT = ROOT / "build" / "grib-samples"
SDISTS = {
    "pygrib==2.1.8": ("pygrib-2.1.8.tar.gz", "7ad941571c02b9afa685cb92fb85fb5ed2cd0e36c4ec40cb74d7782dc7975400",
                      {"pygrib-2.1.8/sampledata/" + n: n for n in
                       ("gfs.t12z.pgrbf120.2p5deg.grib2", "rap.wrfnat.grib2", "rotated_ll.grib1", "eta.grb")}),
    "cfgrib==0.9.15.1": ("cfgrib-0.9.15.1.tar.gz", "d959d8b97e55a63646fa86686b297905ff7f2918a91e3a11d6292dab09598e4d",
                         {"cfgrib-0.9.15.1/tests/sample-data/" + n: n for n in
                          ("era5-levels-members.grib", "regular_gg_ml_g2.grib", "era5-levels-corrupted.grib")}),
}
GRIB1 = "gfs.t12z.pgrbf120.2p5deg.grib1"
NCEP_TABLE2 = {"clwmr": 153, "o3mr": 154}
"""NCEP GRIB1 parameter table 2 (Office Note 388) numbers of the fields ecCodes cannot move to GRIB1 itself."""


def folder():
    return Path(os.environ.get("NEPHELE_GRIB_SAMPLES") or DEFAULT)


def ensure(where=None):
    """The folder holding every sample (fetched and derived when missing)."""
    where = Path(where or folder())
    wanted = [n for _, _, members in SDISTS.values() for n in members.values()] + [GRIB1]
    if all((where / n).is_file() for n in wanted):
        return where
    where.mkdir(parents=True, exist_ok=True)
    for req, (name, sha, members) in SDISTS.items():
        if all((where / n).is_file() for n in members.values()):
            continue
        with tempfile.TemporaryDirectory() as tmp:
            pkg = req.split("==")[0]
            subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", pkg, "-d", tmp, req],
                           check=True, capture_output=True, text=True, timeout=600)
            sdist = Path(tmp) / name
            digest = hashlib.sha256(sdist.read_bytes()).hexdigest()
            if digest != sha:
                raise RuntimeError(f"{name}: sha256 {digest} is not the pinned {sha}")
            with tarfile.open(sdist) as tar:
                for member, out in members.items():
                    data = tar.extractfile(member).read()
                    tmp_out = where / f".{out}.part"
                    tmp_out.write_bytes(data)
                    os.replace(tmp_out, where / out)
    if not (where / GRIB1).is_file():
        to_grib1(where / "gfs.t12z.pgrbf120.2p5deg.grib2", where / GRIB1)
    return where


def to_grib1(src, dst):
    """Re-encode every message ecCodes can move to GRIB1 (simple packing); ``clwmr``/``o3mr`` by their NCEP numbers."""
    import eccodes

    part = dst.with_name(f".{dst.name}.part")
    eccodes.codes_grib_multi_support_on()
    done = {}
    # ecCodes writes an ERROR block to stderr for each field it cannot convert (clwmr, o3mr: handled
    # below); those ~400 lines scared a first `make test`, so they go to a file named in one line
    log = dst.with_name(f".{dst.name}.eccodes.log")
    saved, sink = os.dup(2), os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(sink, 2)
    try:
        with open(src, "rb") as f, open(part, "wb") as out:
            while (h := eccodes.codes_grib_new_from_file(f)) is not None:
                short, level_type = eccodes.codes_get(h, "shortName"), eccodes.codes_get(h, "typeOfLevel")
                level, values = eccodes.codes_get(h, "level"), eccodes.codes_get_values(h)
                try:
                    eccodes.codes_set(h, "packingType", "grid_simple")
                    eccodes.codes_set_values(h, values)
                    eccodes.codes_set(h, "edition", 1)
                    eccodes.codes_write(h, out)
                    done.setdefault(level_type, eccodes.codes_clone(h))
                except eccodes.CodesInternalError:
                    if short in NCEP_TABLE2 and level_type in done:
                        g = eccodes.codes_clone(done[level_type])
                        eccodes.codes_set(g, "indicatorOfParameter", NCEP_TABLE2[short])
                        eccodes.codes_set(g, "level", level)
                        eccodes.codes_set(g, "decimalScaleFactor", 0)  # the template's scaling is for its own field
                        eccodes.codes_set(g, "bitsPerValue", 24)
                        eccodes.codes_set_values(g, values)
                        eccodes.codes_write(g, out)
                        eccodes.codes_release(g)
                finally:
                    eccodes.codes_release(h)
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(sink)
        eccodes.codes_grib_multi_support_off()
        for g in done.values():
            eccodes.codes_release(g)
    os.replace(part, dst)
    print(f"{dst.name}: re-encoded in GRIB1; clwmr and o3mr by NCEP table 2 numbers (ecCodes' messages: {log})")


if __name__ == "__main__":
    print(ensure(sys.argv[1] if len(sys.argv) > 1 else None))
