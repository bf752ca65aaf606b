"""Small command-line values shared by the ``nephele`` commands and the example scripts.

Each raises :class:`~.errors.UsageError` with one line naming the option, so the
CLI exits 2 without a traceback (and ``argparse`` reports it for a ``type=``).
"""

from .errors import UsageError


def parse_size(text, option="--size", *, example="320x240", lo=None, hi=None):
    """``"WxH"`` (any case of ``x``) → ``(W, H)`` ints, each at least ``lo`` and at most ``hi`` when given."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise UsageError(f"{option} must be WxH, e.g. {example}, got {text!r}") from None
    if hi is not None and max(w, h) > hi or lo is not None and min(w, h) < lo:
        raise UsageError(f"{option} {text} is outside {lo}..{hi} pixels" if hi is not None
                         else f"{option} must be at least {lo} pixels each way, got {text!r}")
    return w, h


def parse_range(text, option="--frames", *, lo=None, hi=None):
    """``"A-B"`` or ``"A"`` (non-negative ints) → ``(A, B)`` with ``A <= B``, inside ``lo..hi`` when given."""
    a, sep, b = str(text).partition("-")
    try:
        first, last = int(a), int(b if sep else a)
    except ValueError:
        raise UsageError(f"{option} must look like A-B, got {text!r}") from None
    if last < first:
        raise UsageError(f"{option} {text}: the last is before the first")
    if (lo is not None and first < lo) or (hi is not None and last > hi):
        raise UsageError(f"{option} {text} is outside {lo}-{hi}")
    return first, last


__all__ = ["UsageError", "parse_range", "parse_size"]
