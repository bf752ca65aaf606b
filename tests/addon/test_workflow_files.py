"""The artist's workflow (issue 20): a scene's files belong to it.

The issue: volumes added in an unsaved file went to a shared user folder, and a
second unsaved session overwrote and deleted the frames a saved .blend of the
first pointed to.
"""

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import data_ops, frame, volume_ops  # noqa: E402
from nephele.core.pipeline import cache as core_cache  # noqa: E402

SESSION = r"""
import hashlib, json, sys
from pathlib import Path
import bpy, nephele
bpy.ops.wm.read_factory_settings(use_empty=True)
nephele.register()
from nephele.addon import data_ops, frame, volume_ops
assert bpy.ops.nephele.import_dataset(kind="DEMO_SMALL") == {"FINISHED"}
bpy.context.scene.frame_set(int(sys.argv[1]))
obj, infos = volume_ops.add_volume_clouds("cloud", mode="voxels", voxel_size=0.02,
                                          frames=(int(sys.argv[1]),) * 2)
d = data_ops.layer_dir(frame.params(obj))
print("RESULT " + json.dumps({"dir": str(d), "files": {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
                                                       for p in sorted(d.iterdir())}}))
"""


def _session(tmp_path, frame_number):
    env = dict(os.environ, NEPHELE_CACHE=str(tmp_path / "shared"))
    out = subprocess.run([sys.executable, "-c", SESSION, str(frame_number)], env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    line = next(x for x in out.stdout.splitlines() if x.startswith("RESULT "))
    return json.loads(line[7:])


def _hashes(d):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(Path(d).iterdir())}


def test_a_second_unsaved_session_cannot_touch_the_first_ones_files(tmp_path):
    # Two Blender processes, both unsaved, both baking "Nephele Clouds" with the
    # same user cache folder: the overwrite.  Different frames, so the
    # same file names would hold different contents.
    a = _session(tmp_path, 1)
    b = _session(tmp_path, 20)
    assert a["dir"] != b["dir"]
    assert Path(a["dir"]).is_relative_to(tmp_path / "shared" / "sessions")
    assert not Path(a["dir"]).is_relative_to(Path(b["dir"]).parent.parent)
    assert set(a["files"]) == set(b["files"])  # the same names ...
    assert a["files"]["clouds_0001.vdb"] != b["files"]["clouds_0001.vdb"]  # ... different frames
    assert _hashes(a["dir"]) == a["files"]  # the first session's files are as it left them


def test_session_folder_is_this_process_alone(tmp_path):
    one = core_cache.session_cache_dir(tmp_path)
    assert core_cache.session_cache_dir(tmp_path) == one  # stable within the process
    pid, token = one.name.split("-")
    assert int(pid) == os.getpid() and len(token) == 12
    core_cache._SESSION.pop(str(tmp_path))  # a new process (same pid even) gets a new folder
    two = core_cache.session_cache_dir(tmp_path)
    assert two != one and one.is_dir() and two.is_dir()


def test_ended_sessions_empty_or_old_folders_are_pruned(tmp_path):
    import time

    sessions = tmp_path / "sessions"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    empty, recent, old = (sessions / f"{dead}-{t}" for t in ("aaaaaaaaaaaa", "bbbbbbbbbbbb", "cccccccccccc"))
    live = sessions / f"{os.getppid()}-dddddddddddd"
    for d in (empty, recent, old, live):
        d.mkdir(parents=True)
    for d in (recent, old, live):
        (d / "clouds_0001.vdb").write_bytes(b"v")
    week_ago = time.time() - 8 * 86400
    os.utime(old / "clouds_0001.vdb", (week_ago, week_ago))
    mine = core_cache.session_cache_dir(tmp_path)
    gone = core_cache.prune_sessions(tmp_path)
    assert sorted(gone) == sorted([empty, old])
    assert recent.is_dir() and live.is_dir() and mine.is_dir()


@pytest.fixture
def demo(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "user"))
    assert bpy.ops.nephele.import_dataset(kind="DEMO_SMALL") == {"FINISHED"}
    return empty_scene


def _clouds(scene, frame_number=1):
    obj, _ = volume_ops.add_volume_clouds("cloud", mode="exact", frames=(frame_number, frame_number), scene=scene)
    return obj


def test_saving_moves_the_session_files_beside_the_blend(demo, tmp_path):
    obj = _clouds(demo)
    session_dir = data_ops.layer_dir(frame.params(obj))
    assert session_dir.is_relative_to(tmp_path / "user" / "sessions")
    before = _hashes(session_dir)
    assert {"clouds_0001.vdb", "clouds_0001.exr", "clouds_heights.exr"} <= set(before)

    blend = tmp_path / "films" / "storm.blend"
    blend.parent.mkdir()
    assert bpy.ops.wm.save_as_mainfile(filepath=str(blend)) == {"FINISHED"}
    p = frame.params(obj)
    assert p["directory"] == "//storm_nephele_cache/volumes/Nephele_Clouds"
    assert obj.data.filepath == "//storm_nephele_cache/volumes/Nephele_Clouds/clouds_0001.vdb"
    images = [i for i in bpy.data.images if i.filepath]
    assert images and all(i.filepath.startswith("//storm_nephele_cache/") for i in images)
    new_dir = tmp_path / "films" / "storm_nephele_cache" / "volumes" / "Nephele_Clouds"
    assert _hashes(new_dir) == before
    assert not session_dir.exists()  # moved, not left where another session's cleanup could reach

    # The saved file opens elsewhere in its own right: folder and .blend moved together.
    moved = tmp_path / "elsewhere"
    (tmp_path / "films").rename(moved)
    assert bpy.ops.wm.open_mainfile(filepath=str(moved / "storm.blend")) == {"FINISHED"}
    vol = bpy.data.objects[volume_ops.OBJECT_NAME].data
    assert Path(bpy.path.abspath(vol.filepath)).is_file()
    assert data_ops.layer_dir(frame.params(bpy.data.objects[volume_ops.OBJECT_NAME])) == \
        moved / "storm_nephele_cache" / "volumes" / "Nephele_Clouds"


def test_save_as_copies_from_the_other_file_and_chosen_folders_stay(demo, tmp_path):
    obj = _clouds(demo)
    chosen, _ = volume_ops.add_volume_clouds("cloud", mode="voxels", voxel_size=0.02, frames=(1, 1), scene=demo,
                                             directory=str(tmp_path / "mine"), name="Chosen")
    a, b = tmp_path / "a.blend", tmp_path / "b.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(a))
    a_dir = tmp_path / "a_nephele_cache" / "volumes" / "Nephele_Clouds"
    files = _hashes(a_dir)
    bpy.ops.wm.save_as_mainfile(filepath=str(b))
    # b has its own copy; a's files are still there for a.
    assert _hashes(tmp_path / "b_nephele_cache" / "volumes" / "Nephele_Clouds") == files
    assert _hashes(a_dir) == files
    assert frame.params(obj)["directory"] == "//b_nephele_cache/volumes/Nephele_Clouds"
    # A folder the artist chose is left where it is.
    assert data_ops.layer_dir(frame.params(chosen)) == tmp_path / "mine"
    assert (tmp_path / "mine" / "clouds_0001.vdb").is_file()


def test_save_copy_leaves_the_session_working_and_the_copy_complete(demo, tmp_path):
    obj = _clouds(demo)
    session_dir = data_ops.layer_dir(frame.params(obj))
    files = _hashes(session_dir)
    copy = tmp_path / "copy.blend"
    assert bpy.ops.wm.save_as_mainfile(filepath=str(copy), copy=True) == {"FINISHED"}
    # Still the unsaved session: its layer reads its own folder as before.
    assert bpy.data.filepath == ""
    assert data_ops.layer_dir(frame.params(obj)) == session_dir and _hashes(session_dir) == files
    assert Path(bpy.path.abspath(obj.data.filepath)).parent == session_dir
    # The copy has its own files and points into them.
    assert _hashes(tmp_path / "copy_nephele_cache" / "volumes" / "Nephele_Clouds") == files
    assert bpy.ops.wm.open_mainfile(filepath=str(copy)) == {"FINISHED"}
    reopened = bpy.data.objects[volume_ops.OBJECT_NAME]
    assert frame.params(reopened)["directory"] == "//copy_nephele_cache/volumes/Nephele_Clouds"
    assert Path(bpy.path.abspath(reopened.data.filepath)).is_file()


def test_clear_cache_frees_what_no_layer_uses_and_says_how_much(demo, tmp_path):
    obj = _clouds(demo)
    root = data_ops.cache_dir()
    in_use = _hashes(data_ops.layer_dir(frame.params(obj)))
    stale = root / "volumes" / "Old clouds"
    stale.mkdir(parents=True)
    (stale / "clouds_0001.vdb").write_bytes(b"x" * 3000)
    entry = root / "contour" / "ab" / "abcdef.npz"
    entry.parent.mkdir(parents=True)
    entry.write_bytes(b"y" * 2000)
    freed, removed, kept = data_ops.clear_cache()
    assert (freed, removed) == (5000, 2)
    assert not stale.exists() and not entry.exists()
    assert _hashes(data_ops.layer_dir(frame.params(obj))) == in_use
    assert kept >= sum((data_ops.layer_dir(frame.params(obj)) / n).stat().st_size for n in in_use)
    # The operator says it in one line.
    (stale / "again.vdb").parent.mkdir(parents=True)
    (stale / "again.vdb").write_bytes(b"z" * 1500)
    assert bpy.ops.nephele.clear_cache() == {"FINISHED"}
    assert not stale.exists()
    # Nothing outside this file's own folder is touched.
    assert root.is_relative_to(tmp_path / "user" / "sessions")
