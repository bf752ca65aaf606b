"""A missing kernel library is said aloud once (issue 41): the CLI's stderr, ``nephele info --version``."""

import os
import subprocess
import sys


def _hidden(tmp_path):
    """An environment whose ``nephele_native`` fails to load, as a zip without this platform's library would."""
    fake = tmp_path / "hide" / "nephele_native"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text('raise OSError("libnephele_kernels.so: cannot open shared object file")\n')
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(fake.parent), *sys.path])}


def _nephele(env, *args, timeout=600):
    return subprocess.run([sys.executable, "-m", "nephele.farm.cli", *args], capture_output=True, text=True,
                          env=env, timeout=timeout)


def test_info_version_says_which_kernels_run(tmp_path):
    run = _nephele({**os.environ}, "info", "--version")
    assert run.returncode == 0 and run.stdout.startswith("nephele ") and "\nkernels " in run.stdout
    hidden = _nephele(_hidden(tmp_path), "info", "--version")
    assert hidden.returncode == 0
    assert "kernels NumPy twins (libnephele_kernels.so: cannot open shared object file)" in hidden.stdout
    notes = [ln for ln in hidden.stderr.splitlines() if "note:" in ln]
    assert notes == ["nephele info: note: the compiled kernels are not loaded (libnephele_kernels.so: cannot open "
                     "shared object file); their NumPy twins run instead, 2-4x slower: install the zip for this "
                     "platform, or the nephele_native wheel"], hidden.stderr
    assert _nephele({**os.environ, "NEPHELE_NATIVE": "0"}, "info", "--version").stderr == ""  # chosen: no notice


def test_muscle_with_the_kernels_hidden_prints_one_notice(tmp_path):
    run = _nephele(_hidden(tmp_path), "muscle", "--export", "ply", "--frames", "1", "--out", str(tmp_path / "m"),
                   "--spacing", "1.6")
    assert run.returncode == 0, run.stderr[-2000:]
    assert [ln for ln in run.stderr.splitlines() if "note:" in ln] == [
        "nephele muscle: note: the compiled kernels are not loaded (libnephele_kernels.so: cannot open shared object "
        "file); their NumPy twins run instead, 2-4x slower: install the zip for this platform, or the nephele_native "
        "wheel"]
    assert (tmp_path / "m" / "frame_0001.ply").stat().st_size > 0


def test_the_notice_comes_once_per_process(monkeypatch):
    from nephele.core import native

    heard = []
    monkeypatch.setitem(native._FALLBACK, "listeners", [])
    monkeypatch.setitem(native._FALLBACK, "reason", None)
    monkeypatch.setitem(sys.modules, "nephele_native", None)  # import fails: ImportError
    monkeypatch.delenv("NEPHELE_NATIVE", raising=False)
    native._module.cache_clear()
    try:
        native.on_fallback(heard.append)
        for _ in range(5):
            assert native.kernel("anything", None, []) is None
        assert len(heard) == 1 and "not loaded (import of nephele_native halted" in heard[0]
        assert native.status().startswith("NumPy twins (import of nephele_native halted")
        late = []
        native.on_fallback(late.append)  # a listener added afterwards hears it at once
        assert late == heard
    finally:
        native._module.cache_clear()
