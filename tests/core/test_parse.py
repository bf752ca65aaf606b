"""The one reader of "WxH" sizes and "A-B" ranges (CLI commands and example scripts)."""

import argparse

import pytest

from nephele.core.errors import UsageError
from nephele.core.parse import parse_range, parse_size


def test_size():
    assert parse_size("320x240") == (320, 240)
    assert parse_size("64X48") == (64, 48)
    assert parse_size("8x8192", lo=8, hi=8192) == (8, 8192)


@pytest.mark.parametrize("text, kw, words", [
    ("wide", {}, ["--size", "WxH", "'wide'"]),
    ("3x4x5", {}, ["WxH"]),
    ("7x100", {"lo": 8, "hi": 8192}, ["--size 7x100", "8..8192"]),
    ("0x5", {"lo": 1}, ["at least 1", "'0x5'"]),
])
def test_bad_size(text, kw, words):
    with pytest.raises(UsageError) as err:
        parse_size(text, **kw)
    assert all(w in str(err.value) for w in words), str(err.value)


def test_range():
    assert parse_range("3-7") == (3, 7)
    assert parse_range("5") == (5, 5)
    assert parse_range("0-23", "--steps", lo=0, hi=23) == (0, 23)


@pytest.mark.parametrize("text, kw, words", [
    ("one-ten", {}, ["--frames must look like A-B", "'one-ten'"]),
    ("-3", {}, ["A-B"]),
    ("5-1", {}, ["--frames 5-1", "last is before the first"]),
    ("3-4", {"lo": 0, "hi": 1}, ["--frames 3-4 is outside 0-1"]),
])
def test_bad_range(text, kw, words):
    with pytest.raises(UsageError) as err:
        parse_range(text, **kw)
    assert all(w in str(err.value) for w in words), str(err.value)


def test_argparse_type_reports_one_line(capsys):
    ap = argparse.ArgumentParser(prog="fig")
    ap.add_argument("--size", type=parse_size)
    assert ap.parse_args(["--size", "48x36"]).size == (48, 36)
    with pytest.raises(SystemExit):
        ap.parse_args(["--size", "big"])
    assert "--size" in capsys.readouterr().err
