"""Where tasks get their data: named sources opened once per process, and frame times.

A source is a file path, ``demo:<size>`` (the synthetic climate) or a name
given to an in-memory dataset with :func:`register_source`.  Every task of
every figure opens its data with :func:`open_source`, which keeps the few
last-opened datasets (their lazily read time steps stay cached) and reopens a
file whose identity (:func:`~nephele.core.pipeline.cache.source_stamp`) changed.
"""

from collections import OrderedDict

from .cache import source_stamp

_OPEN = OrderedDict()
_OPEN_MAX = 3
_MEMORY = {}


def register_source(name, dataset):
    """Make an in-memory :class:`~nephele.core.climate.dataset.Dataset` available as source ``name``.

    For data built in a session (and tests); such a source exists only in
    this process, so the farm cannot precompute it.
    """
    _MEMORY[str(name)] = dataset
    return str(name)


def open_source(source):
    """Open the dataset ``source`` ("demo", "demo:small", a .nc or .ctl path), once per process.

    Datasets read lazily and keep only a few steps, so holding the last few
    open is cheap; a file changed on disk is opened again.
    """
    source = str(source)
    if source in _MEMORY:
        return _MEMORY[source]
    from ..climate.readers import open_dataset

    stamp = source_stamp(source)
    hit = _OPEN.get(source)
    if hit is not None and hit[0] == stamp:
        _OPEN.move_to_end(source)
        return hit[1]
    ds = open_dataset(source)
    _OPEN[source] = (stamp, ds)
    while len(_OPEN) > _OPEN_MAX:
        _OPEN.popitem(last=False)
    return ds


def open_with_overrides(source, **kw):
    """``(dataset, source name)`` of ``source`` read with the reader overrides ``kw`` (see
    :func:`~nephele.core.climate.readers.open_dataset`).

    Without overrides: :func:`open_source` and ``source`` itself.  With them the
    name is :func:`~nephele.core.climate.readers.override_source`'s
    ``SOURCE?key=value&...`` plus ``&file=ID``, a hash of the file's path, size and
    modification time, so that cached results of other overrides or of an older
    file are never reused; the dataset is registered under it for this process,
    and any other process (a farm worker, a saved scene) opens the name again.
    """
    if not kw:
        return open_source(source), str(source)
    import hashlib

    from ..climate.readers import open_dataset, override_source

    ds = open_dataset(source, **kw)
    file_id = hashlib.sha256(source_stamp(source).encode()).hexdigest()[:12]
    return ds, register_source(f"{override_source(source, **kw)}&file={file_id}", ds)


def frame_hours(frame, frame_start=1, hours_per_frame=1.0, last_hour=None):
    """Model time (hours since the first step) shown at ``frame``, clamped to ``[0, last_hour]``."""
    if not hours_per_frame > 0:
        raise ValueError(f"hours_per_frame must be > 0, got {hours_per_frame}")
    hours = (float(frame) - float(frame_start)) * float(hours_per_frame)
    hours = max(hours, 0.0)
    if last_hour is not None:
        hours = min(hours, float(last_hour))
    return hours


__all__ = ["frame_hours", "open_source", "open_with_overrides", "register_source"]
