"""The compiled kernels (the ``nephele_native`` wheel, built from ``native/``) where installed.

Each kernel has a NumPy twin in the module that calls it, used where the wheel is not
installed (platforms it is not built for) or when ``NEPHELE_NATIVE=0``.  Results of the
two agree to the tolerances their tests state, not bit for bit, so cache keys carry
:func:`identity` (see :mod:`.pipeline.codehash`).
"""

import os
from functools import lru_cache

_FALLBACK = {"reason": None, "listeners": []}


def on_fallback(listener):
    """Call ``listener(text)`` once, with :func:`notice`'s line, when the kernels turn out to be missing.

    The CLI prints it on stderr (once per run), the add-on in its panel; a listener added after the
    fallback is called at once.
    """
    _FALLBACK["listeners"].append(listener)
    if _FALLBACK["reason"] is not None:
        listener(notice())


def notice():
    """One line saying the compiled kernels are missing and what that costs, or None when they load (or are off)."""
    reason = _FALLBACK["reason"]
    if reason is None:
        return None
    return (f"the compiled kernels are not loaded ({reason}); their NumPy twins run instead, 2-4x slower: "
            "install the zip for this platform, or the nephele_native wheel")


def status():
    """What runs: ``"compiled (BUILD_ID)"``, ``"NumPy twins (NEPHELE_NATIVE=0)"`` or ``"NumPy twins (<why>)"``."""
    mod = _module()
    if mod is not None:
        return f"compiled ({mod.BUILD_ID})"
    return f"NumPy twins ({_FALLBACK['reason'] or 'NEPHELE_NATIVE=0'})"


@lru_cache(maxsize=None)
def _module():
    if os.environ.get("NEPHELE_NATIVE", "1") == "0":
        return None  # chosen by the user: nothing to announce
    try:
        import nephele_native
    except (ImportError, OSError) as exc:  # not installed, or its library does not load here
        _FALLBACK["reason"] = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:160]
        for listener in _FALLBACK["listeners"]:
            listener(notice())
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
