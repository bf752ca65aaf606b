"""``nephele film``: argument errors before anything renders, the reel's plan and cut, and (slow) real reels
through the farm: every segment alone, a worker killed mid-reel, resume."""

import json
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from nephele.farm import cli, reel

BAD = [
    (["--only", "fig9"], "unknown figure fig9"),
    (["--only", ","], "unknown figure"),
    (["--days", "0"], "positive number of model days"),
    (["--days", "-3"], "positive number of model days"),
    (["--days", "nan"], "positive number of model days"),
    (["--days", "11"], "needs 264 hours of data; demo has 240"),
    (["--days", "0.01"], "not a whole number of model hours"),
    (["--days", "10", "--only", "fig1"], "cannot be combined with --only"),
    (["--frames", "0"], "--frames must be >= 1"),
    (["--samples", "0"], "--samples must be >= 1"),
    (["--size", "8x8"], "outside 16..8192"),
    (["--size", "wide"], "--size must be WxH"),
    (["--name", "../x"], "--name must be a plain file name"),
    (["--source", "/nonexistent/file.nc"], "/nonexistent/file.nc"),
    (["--timeout", "0"], "--timeout must be > 0"),
]


@pytest.fixture
def no_render(monkeypatch):
    """Rendering or starting a cluster fails the test: errors must come first."""
    from nephele.farm import cluster, render

    def boom(*a, **k):
        raise AssertionError("rendering started")

    monkeypatch.setattr(render, "render_sequence", boom)
    monkeypatch.setattr(cluster, "open_client", boom)
    monkeypatch.setattr(cluster, "local_cluster", boom)


@pytest.mark.parametrize("argv,message", BAD)
def test_bad_arguments_exit_2_with_one_line(argv, message, tmp_path, capsys, no_render):
    out = tmp_path / "reel"
    assert cli.main(["film", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and err[0].startswith("nephele film: error:")
    assert not (out / "frames").exists()


def test_unwritable_output_folder_exits_2(tmp_path, capsys, no_render):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    assert cli.main(["film", "--out", str(blocker / "reel")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "output directory cannot be written" in err[0]


def test_dry_run_prints_the_plan_and_renders_nothing(tmp_path, capsys, no_render):
    assert cli.main(["film", "--out", str(tmp_path), "--only", "fig6,fig1", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert out.index("fig1:") < out.index("fig6:") and "frames 1-6 480x270" in out
    assert not (tmp_path / "frames").exists()


def test_plan_follows_the_paper():
    shots = reel.plan("/tmp/x")
    assert [s.key for s in shots] == ["fig1", "fig2", "fig3", "fig4", "fig5", "fig6", "fig7", "dome"]
    assert all(s.frames == 6 and s.size == (480, 270) for s in shots)
    assert [s.key for s in reel.plan("/tmp/x", only="dome,fig4")] == ["fig4", "dome"]
    final = {s.key: s for s in reel.plan("/tmp/x", "final")}
    assert final["fig1"].frames == 240 and final["fig6"].frames == 120 and final["fig1"].size == (1920, 1080)
    assert final["fig1"].options["hours_per_frame"] == 1.0 and final["fig1"].options["haze"] == "volume"
    # the splats in EEVEE at both qualities (a final Cycles frame of them: past 23 min on 2 cores), the rest in Cycles
    assert final["fig3"].engine == shots[2].engine == "BLENDER_EEVEE" and final["fig3"].samples == 32
    assert all(s.engine is None for s in final.values() if s.key != "fig3")
    assert final["fig6"].options["grid"] == [64, 64, 48] and "grid" not in shots[5].options  # preview: the example's
    # a different option, a different folder: resume never mixes frames made otherwise
    a, b = reel.plan("/tmp/x", only="fig1")[0], reel.plan("/tmp/x", only="fig1", annotate=False)[0]
    assert a.out_dir != b.out_dir and a.out_dir == reel.plan("/tmp/x", only="fig1")[0].out_dir


def test_ten_days_is_fig4_at_one_frame_per_model_hour():
    from nephele.farm.cmd_film import check_days

    (shot,) = reel.plan("/tmp/x", days=10)
    assert shot.key == "fig4" and shot.frames == 240
    assert shot.options["frames"] == [1, 240] and shot.options["hours_per_frame"] == 1.0
    assert check_days(10, "demo") == 240 and check_days(0.5, "demo:small") == 12


def test_cut_lays_out_cards_frames_and_holds():
    shots = reel.plan("/tmp/x", only="fig1,dome", frames=3, size=(32, 18))
    paths = {s.key: [Path(f"/f/{s.key}/frame_{i:04d}.png") for i in (1, 2, 3)] for s in shots}
    side = {"fig1": (18, 32), "dome": (18, 18)}

    def read(p):
        key, i = p.parent.name, int(p.stem[-1])
        return np.full(side[key] + (3,), i / 4.0, np.float32)

    cards = {"fig1": np.ones((18, 32, 3), np.float32), "dome": None}
    out = list(reel.pictures(shots, paths, cards, (32, 18), fps=4, hold=2, title_s=1.0, tail_s=0.5, read=read))
    assert len(out) == reel.reel_length(shots, cards, fps=4, hold=2, title_s=1.0, tail_s=0.5)
    labels = [str(label) for label, _ in out]
    assert labels[:4] == ["fig1 title card"] * 4 and labels[4:6] == ["fig1 fade"] * 2
    assert labels[6:12] == [str(paths["fig1"][i]) for i in (0, 0, 1, 1, 2, 2)]
    assert labels[12:14] == [str(paths["fig1"][2])] * 2  # the last frame held
    dome = [rgb for label, rgb in out if "/dome/" in str(label)]
    assert dome[0].shape == (18, 32, 3) and dome[0][:, :7].max() == 0 and dome[0][:, 7:25].min() == 64
    assert all(rgb.dtype == np.uint8 for _, rgb in out)


# ------------------------------------------------------------------ real reels through the farm (bpy, slow)


def _mp4_frames(path):
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    w, h = meta["size"]
    return [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in reader]


def _film(cluster, out, *argv):
    return cli.main(["film", "--out", str(out), "--scheduler", cluster.scheduler_address, "--quiet",
                     "--size", "64x36", "--samples", "1", "--source", "demo:small", *argv])


@pytest.mark.slow
@pytest.mark.parametrize("key", reel.KEYS)
def test_only_each_figure(key, farm_cluster, tmp_path):
    """Each segment alone renders, moves between its frames, and lands in the MP4 after its title card."""
    pytest.importorskip("bpy")
    assert _film(farm_cluster, tmp_path, "--only", key, "--frames", "2") == 0
    summary = json.loads((tmp_path / "film.json").read_text())
    (seg,) = summary["segments"]
    assert seg["key"] == key and seg["rendered"] == 2
    folder = tmp_path / seg["folder"]
    from nephele.farm.post import read_rgba

    a, b = (read_rgba(folder / f"frame_000{i}.png")[..., :3] for i in (1, 2))
    assert a.mean() > 0.02 and b.mean() > 0.02  # not black
    assert np.abs(a - b).max() > 0.05  # it moves
    frames = _mp4_frames(tmp_path / "reel.mp4")
    assert len(frames) == round(summary["seconds_of_film"] * summary["fps"])
    assert (tmp_path / "contact_sheet.png").stat().st_size > 0 and (tmp_path / "cards" / f"{key}.png").is_file()


@pytest.mark.slow
def test_kill_worker_mid_reel_then_resume(farm_cluster, tmp_path):
    """kill -9 of a worker while it renders a frame of the reel: nothing is lost; a resume renders only
    missing frames."""
    pytest.importorskip("bpy")
    from distributed import Client

    argv = ("--only", "fig1,dome", "--frames", "6")
    box = {}
    t = threading.Thread(target=lambda: box.setdefault("rc", _film(farm_cluster, tmp_path, *argv)))
    t.start()
    victim, deadline = None, time.time() + 600
    with Client(farm_cluster.scheduler_address) as client:
        while victim is None and time.time() < deadline:  # a worker in the middle of a frame of the reel
            busy = [w for w, keys in client.processing().items() if any("nephele-frames" in k for k in keys)]
            if busy and list(tmp_path.glob("frames/fig1-*/frame_0001.png")):
                victim = client.run(os.getpid, workers=busy[:1])[busy[0]]
            time.sleep(0.05)
    assert victim is not None
    os.kill(victim, signal.SIGKILL)
    t.join(900)
    assert box["rc"] == 0
    summary = json.loads((tmp_path / "film.json").read_text())
    entries = []
    for seg in summary["segments"]:
        manifest = json.loads((tmp_path / seg["folder"] / "manifest.json").read_text())
        assert sorted(int(f) for f in manifest["frames"]) == [1, 2, 3, 4, 5, 6]
        assert all(e["status"] == "ok" for e in manifest["frames"].values())
        entries += manifest["frames"].values()
    assert any(e["attempts"] >= 2 or e.get("recovered") for e in entries)  # the killed frame was done again
    (tmp_path / summary["segments"][0]["folder"] / "frame_0002.png").unlink()
    (tmp_path / summary["segments"][1]["folder"] / "frame_0005.png").unlink()
    assert _film(farm_cluster, tmp_path, *argv) == 0
    again = json.loads((tmp_path / "film.json").read_text())
    assert [(s["rendered"], s["kept"]) for s in again["segments"]] == [(1, 5), (1, 5)]
    assert len(_mp4_frames(tmp_path / "reel.mp4")) == round(again["seconds_of_film"] * again["fps"])
