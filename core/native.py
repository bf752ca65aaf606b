"""The compiled kernels (the ``nephele_native`` wheel, built from ``native/``) where installed.

Each kernel has a NumPy twin in the module that calls it, used where the wheel is not
installed (platforms it is not built for) or when ``NEPHELE_NATIVE=0``.  Results of the
two agree to the tolerances their tests state, not bit for bit, so cache keys carry
:func:`identity` (see :mod:`.pipeline.codehash`).
"""

import os
from functools import lru_cache


@lru_cache(maxsize=None)
def _module():
    if os.environ.get("NEPHELE_NATIVE", "1") == "0":
        return None
    try:
        import nephele_native
    except (ImportError, OSError):  # OSError: a library the loader refuses (another arch, a damaged file)
        return None
    return nephele_native


def kernel(name, restype, argtypes):
    """The ctypes function ``name`` of the compiled library with its types set, or None
    without the library.  A library lacking ``name`` is a stale build: AttributeError."""
    mod = _module()
    if mod is None:
        return None
    fn = getattr(mod.lib, name)
    fn.restype, fn.argtypes = restype, argtypes
    return fn


def identity():
    """Which kernels this process runs: the library's build id, or ``"numpy"``."""
    mod = _module()
    return "numpy" if mod is None else mod.BUILD_ID
