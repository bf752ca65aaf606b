"""Memory before it runs out: how much this process may still allocate, and one refusal.

Every operation whose memory grows with its input (volumes, splats, blobby
meshes, scattering solves, flow volumes, contours of huge grids, readers
trusting a header) estimates its peak and calls :func:`check_memory` before
allocating, so an impossible request fails in one line naming the size and
what to change, instead of the machine swapping or the process being killed
half-way through a file.

"Available" is the least of (each where the platform has it):

* the machine's free memory: ``MemAvailable`` of ``/proc/meminfo`` on Linux;
  elsewhere free pages from ``os.sysconf`` (BSDs: a low estimate, the page cache it
  leaves out could be reclaimed; macOS has no free-page count, so its physical memory
  bounds a request there);
  on Windows ``GlobalMemoryStatusEx``'s available physical memory, through ctypes;
* the container's limit: cgroup v2 ``memory.max`` less ``memory.current``
  (or cgroup v1's limit less usage), as Slurm and Docker set it;
* this process's own limits: ``ulimit -v`` (``RLIMIT_AS``) less its virtual size,
  ``ulimit -d`` (``RLIMIT_DATA``) less its data segment;
* ``NEPHELE_MEMORY_LIMIT`` (bytes, or with a K/M/G/T suffix), for a user sharing a node.

No psutil: Blender's Python does not ship it.
"""

import os
import sys

from .errors import DataError

_UNITS = {"": 1, "B": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def parse_bytes(text):
    """``"2G"`` → 2147483648 (binary units; a plain number is bytes); None for empty text."""
    text = str(text or "").strip().upper().removesuffix("IB").removesuffix("B")
    if not text:
        return None
    unit = text[-1] if text[-1] in _UNITS else ""
    try:
        value = float(text[: len(text) - len(unit)])
    except ValueError:
        raise DataError(f"is not a size such as 8G or 512M: {text!r}", field="NEPHELE_MEMORY_LIMIT") from None
    return int(value * _UNITS[unit])


def _read_int(path):
    try:
        with open(path) as f:
            text = f.read().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _machine():
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    if sys.platform == "win32":
        return _windows()
    for pages in ("SC_AVPHYS_PAGES", "SC_PHYS_PAGES"):  # macOS has only the second: an upper bound
        try:
            return int(os.sysconf(pages)) * int(os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError, AttributeError):
            pass
    return None


def _windows():
    import ctypes

    class Status(ctypes.Structure):
        _fields_ = [("dwLength", ctypes.c_ulong), ("dwMemoryLoad", ctypes.c_ulong),
                    ("ullTotalPhys", ctypes.c_ulonglong),
                    ("ullAvailPhys", ctypes.c_ulonglong), ("ullTotalPageFile", ctypes.c_ulonglong),
                    ("ullAvailPageFile", ctypes.c_ulonglong), ("ullTotalVirtual", ctypes.c_ulonglong),
                    ("ullAvailVirtual", ctypes.c_ulonglong), ("ullAvailExtendedVirtual", ctypes.c_ulonglong)]

    s = Status()
    s.dwLength = ctypes.sizeof(Status)
    try:
        if ctypes.windll.kernel32.GlobalMemoryStatusEx(ctypes.byref(s)):
            return int(s.ullAvailPhys)
    except (AttributeError, OSError):
        pass
    return None


def _cgroup():
    """Bytes left under this process's cgroup limit, or None when there is none."""
    try:
        with open("/proc/self/cgroup") as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    for line in lines:
        _, controllers, rel = line.split(":", 2)
        if controllers == "":  # v2: one unified hierarchy
            base = "/sys/fs/cgroup" + rel.rstrip("/")
            limit, used = _read_int(base + "/memory.max"), _read_int(base + "/memory.current")
        elif "memory" in controllers.split(","):
            base = "/sys/fs/cgroup/memory" + rel.rstrip("/")
            limit, used = _read_int(base + "/memory.limit_in_bytes"), _read_int(base + "/memory.usage_in_bytes")
        else:
            continue
        if limit is not None and limit < 1 << 60:  # v1 writes a huge number for "no limit"
            return max(limit - (used or 0), 0)
    return None


def _status(key):
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _rlimits():
    """Bytes left under ``ulimit -v`` and ``ulimit -d`` (None where unlimited or unknown)."""
    try:
        import resource
    except ImportError:  # Windows
        return None
    left = []
    for limit, key in ((resource.RLIMIT_AS, "VmSize:"), (getattr(resource, "RLIMIT_DATA", None), "VmData:")):
        if limit is None:
            continue
        soft = resource.getrlimit(limit)[0]
        used = _status(key)
        if soft != resource.RLIM_INFINITY and used is not None:
            left.append(max(soft - used, 0))
    return min(left) if left else None


def available_memory():
    """Bytes this process can still allocate (the least of the limits in the module docstring), or None if unknown."""
    known = [v for v in (_machine(), _cgroup(), _rlimits(), parse_bytes(os.environ.get("NEPHELE_MEMORY_LIMIT")))
             if v is not None]
    return min(known) if known else None


def format_bytes(n):
    """``1536`` → ``"1.5 KB"`` (decimal units, as file managers show)."""
    n = float(n)
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if abs(n) < 1000.0 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0


def check_memory(need, what, *, hint=None, available=None, path=None, field=None):
    """Raise :class:`~.errors.DataError` when ``need`` bytes exceed the memory available; returns ``need``.

    Parameters
    ----------
    need : int or float
        The operation's estimated peak, in bytes.
    what : str
        What needs it, e.g. ``"splatting 2,000,000 particles on a 512³ grid"``.
    hint : str, optional
        What the user can change: ``"a coarser --resolution"``, ``"fewer bins per face"``.
    available : int, optional
        Bytes available (default :func:`available_memory`).
    path, field : optional
        Named in the message, as :class:`~.errors.DataError` does.
    """
    have = available_memory() if available is None else available
    if have is not None and need > have:
        tail = f"; {hint}" if hint else ""
        raise DataError(f"{what} needs about {format_bytes(need)} of memory, more than the {format_bytes(have)} "
                        f"available{tail}", path=path, field=field)
    return need


__all__ = ["available_memory", "check_memory", "format_bytes", "parse_bytes"]
