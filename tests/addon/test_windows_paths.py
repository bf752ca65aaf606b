"""The add-on's path comparisons with Windows paths: a file named in another letter case is the same
file there (a save onto the open .blend is no "save copy"; a frame under the cache folder is moved)."""

import ntpath
import posixpath
from pathlib import PurePosixPath, PureWindowsPath

import pytest

pytest.importorskip("bpy")

from nephele.addon.data_ops import rebased, same_file_name  # noqa: E402


def test_same_blend_in_another_letter_case_on_windows():
    assert same_file_name(r"C:\Films\Storm.blend", r"c:\films\STORM.blend", path=ntpath)
    assert same_file_name(r"C:\Films\.\Storm.blend", "C:/Films/Storm.blend", path=ntpath)
    assert not same_file_name(r"C:\Films\Storm.blend", r"D:\Films\Storm.blend", path=ntpath)
    assert not same_file_name("/films/Storm.blend", "/films/storm.blend", path=posixpath)  # Linux: two files


def test_frames_rebased_whatever_the_letter_case_on_windows():
    old, new = PureWindowsPath(r"C:\Users\Ann\AppData\nephele\sessions\12-ab"), PureWindowsPath(r"D:\film_cache")
    frame = PureWindowsPath(r"c:\users\ann\appdata\Nephele\sessions\12-AB\volumes\Clouds\clouds_0001.vdb")
    assert rebased(frame, old, new) == PureWindowsPath(r"D:\film_cache\volumes\Clouds\clouds_0001.vdb")
    assert rebased(old, old, new) == new
    assert rebased(PureWindowsPath(r"C:\Users\Ann\AppData\nephele\sessions\12-abc\x.vdb"), old, new) is None
    assert rebased(PurePosixPath("/cache/A/x.vdb"), PurePosixPath("/cache/a"), PurePosixPath("/new")) is None
