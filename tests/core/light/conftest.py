"""The scattering tests' two paths: ``kernels`` (indirect parameter) runs a test with the compiled
kernels (``"native"``, skipped where the nephele_native wheel is not installed) or with their NumPy
twins (``"numpy"``, as with ``NEPHELE_NATIVE=0``); unparametrized tests take whichever is installed.
:data:`kernel_paths.BOTH` puts the NumPy run of an expensive case in the slow tier."""

import pytest

from nephele.core import native


@pytest.fixture
def kernels(request, monkeypatch):
    path = getattr(request, "param", "installed")
    if path == "numpy":
        monkeypatch.setattr(native, "_module", lambda: None)
    elif path == "native" and native.identity() == "numpy":
        pytest.skip("no compiled kernels installed")
    return path
