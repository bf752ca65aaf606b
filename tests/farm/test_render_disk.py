"""Nothing lost when the output fills, is read-only, is shared by two runs or has a damaged manifest (issue 41).

The disk-full runs use the real CLI in a subprocess (one line on stderr, an
exit status, no traceback) on a tmpfs of a few hundred KB (the
``small_disk`` fixture: root, as in CI).
"""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("bpy")

from nephele.farm import cli  # noqa: E402
from nephele.farm.frames import check_image, frame_name  # noqa: E402
from nephele.farm.render import render_sequence  # noqa: E402

SCENE = Path(__file__).with_name("cube_scene.py")
BIG = ["--set", "size=[160,120]"]  # ~10 KB Workbench frames


def nephele(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "nephele.farm.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, "PYTHONUNBUFFERED": "1"})


def error_lines(stderr):
    """The stderr lines that are not the progress bar; no traceback may be among them."""
    lines = [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("nephele render [")]
    assert not any("Traceback" in ln for ln in lines), stderr[-3000:]
    return lines


def frames_in(out):
    return sorted(int(p.stem.split("_")[1]) for p in Path(out).glob("frame_*.png"))


def test_read_only_output_is_refused_before_rendering(small_disk, capsys):
    disk = small_disk("64k")
    small_disk.remount(disk, "ro")
    t0 = time.perf_counter()
    code = cli.main(["render", str(SCENE), "--frames", "1-3", "--out", str(disk / "out")])
    err = capsys.readouterr().err
    assert code == 2 and time.perf_counter() - t0 < 5.0  # before any worker starts
    assert err.strip().splitlines() == [f"nephele render: error: {disk / 'out'}: field '--out': output directory "
                                        "cannot be written: Read-only file system"]


def test_full_disk_estimate_then_stop_then_resume(small_disk):
    """The done-when of issue 41 on a small scene: refused up front from the first frame's size; with --force
    the run stops at the full disk in one line, every frame there decodes; after freeing space the same
    command renders only what is missing."""
    disk = small_disk("160k")
    out = disk / "out"
    args = ["render", SCENE, "--frames", "1-40", "--out", out, "--workers", "1", *BIG]

    run = nephele(*args)
    lines = error_lines(run.stderr)
    assert run.returncode == 2, run.stderr[-3000:]
    assert len(lines) == 1 and lines[0].startswith(f"nephele render: error: {out}: the 39 frames left"), lines
    assert "--force" in lines[0]
    assert frames_in(out) == [1]

    run = nephele(*args, "--force")
    lines = error_lines(run.stderr)
    assert run.returncode == 2, run.stderr[-3000:]
    assert len(lines) == 1 and "no space left on the disk" in lines[0] and str(out) in lines[0], lines
    written = frames_in(out)
    assert 3 <= len(written) < 40 and written == list(range(1, len(written) + 1))
    for f in written:
        check_image(out / frame_name(f))  # every frame there is whole
    assert not list(out.glob(".*.tmp*")) and not (out / ".nephele-tmp").exists()  # no temporary left

    small_disk.remount(disk, "size=4m")  # space freed
    run = nephele(*args)
    assert run.returncode == 0, run.stderr[-3000:]
    assert f"40/40 frames valid in {out} ({40 - len(written)} rendered, {len(written)} already there)" in run.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert sorted(map(int, manifest["frames"])) == list(range(1, 41))
    assert all(e["status"] == "ok" for e in manifest["frames"].values())
    for f in range(1, 41):
        check_image(out / frame_name(f))


def test_two_renders_into_one_folder(tmp_path):
    """Two `nephele render` runs at once into one --out: the second refuses in one line, the first finishes;
    every frame valid and the manifest complete."""
    out = tmp_path / "out"
    args = [sys.executable, "-m", "nephele.farm.cli", "render", str(SCENE), "--frames", "1-6", "--out", str(out),
            "--workers", "1", "--quiet", "--set", "delay=0.5"]
    first = subprocess.Popen(args, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not (out / ".nephele.lock").exists() and time.time() < deadline:
        time.sleep(0.05)
    second = subprocess.run(args, capture_output=True, text=True, timeout=300)
    err1 = first.communicate(timeout=600)[1]
    assert first.returncode == 0, err1[-3000:]
    assert second.returncode == 2
    lines = error_lines(second.stderr)
    assert len(lines) == 1 and f"{out}: another nephele render (pid {first.pid} on " in lines[0], lines
    manifest = json.loads((out / "manifest.json").read_text())
    assert sorted(map(int, manifest["frames"])) == list(range(1, 7))
    for f in range(1, 7):
        assert manifest["frames"][str(f)]["status"] == "ok"
        check_image(out / frame_name(f))
    assert not (out / ".nephele.lock").exists()
    # Now free: the same command finds everything done.
    again = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and again.stderr.count("6/6 frames valid") == 1, again.stderr


def test_damaged_manifest_is_moved_aside_and_the_render_goes_on(farm_cluster, tmp_path, capsys):
    out = tmp_path / "out"
    res = render_sequence(SCENE, "1-3", out, scheduler=farm_cluster.scheduler_address, progress=False)
    assert res.ok
    (out / "manifest.json").write_text('{"version": 1, "frames": {"1": ')  # cut short
    capsys.readouterr()
    res = render_sequence(SCENE, "1-4", out, scheduler=farm_cluster.scheduler_address, progress=False)
    err = capsys.readouterr().err
    assert res.ok and res.skipped == [1, 2, 3] and res.rendered == [4]  # whole frames adopted, only 4 rendered
    bad = list(out.glob("manifest.json.bad-*"))
    assert len(bad) == 1 and bad[0].read_text() == '{"version": 1, "frames": {"1": '  # its history kept
    warning = [ln for ln in err.splitlines() if "warning" in ln]
    assert (len(warning) == 1 and f"{out / 'manifest.json'}: is not valid JSON" in warning[0]
            and bad[0].name in warning[0])
    assert sorted(map(int, json.loads((out / "manifest.json").read_text())["frames"])) == [1, 2, 3, 4]
