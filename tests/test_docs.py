"""The documentation: the README stays short, and the site builds offline with warnings as errors."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README_MAX_LINES = 250


def test_readme_fits_a_first_minute():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; move detail into docs/"
    # The two commands come first: the first code block is `make demo` / `make test`.
    first_block = (ROOT / "README.md").read_text().split("```")[1]
    assert "make demo" in first_block and "make test" in first_block


def test_readme_links_point_at_files():
    import re

    text = (ROOT / "README.md").read_text()
    targets = [t.split("#")[0] for t in re.findall(r"\]\(([^)\s]+)\)", text) if "://" not in t]
    missing = [t for t in targets if t and not (ROOT / t).exists()]
    assert not missing, missing


@pytest.mark.slow
def test_docs_build_without_warnings(tmp_path):
    res = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-b", "html", "-q",
         "-d", str(tmp_path / "doctrees"), str(ROOT / "docs"), str(tmp_path / "html")],
        capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-4000:]
    html = tmp_path / "html"
    figures = sorted(p.name for p in (html / "figures").glob("fig*.html"))
    assert figures == ["fig1-contours.html", "fig2-volume.html", "fig3-splats.html",
                       "fig4-advected-texture.html", "fig5-flow-volumes.html", "fig6-scattering.html",
                       "fig7-muscle.html"]
    api = "".join(p.read_text() for p in (html / "api").glob("*.html"))
    for name in ("climate.open_dataset", "surface.isosurface", "volume.resample", "light.solve",
                 "muscle.blobby_surface", "flowvol.flow_volume", "splats.splat_kernel", "camera.dome_camera",
                 "volume.TransferFunction"):
        assert f'id="nephele.core.{name}"' in api, name
    # Every picture a page shows was copied into the site.
    assert len(list((html / "_images").glob("*"))) >= 20
