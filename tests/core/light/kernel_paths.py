"""Parameters of the ``kernels`` fixture (tests/core/light/conftest.py)."""

import pytest

# the compiled kernels in the quick tier, their NumPy twins in the slow one (a cheaper case of the
# same property runs on NumPy in the quick tier: test_scatter_voxel_depth.test_numpy_twin_*)
BOTH = [pytest.param("native"), pytest.param("numpy", marks=pytest.mark.slow)]
# both in the quick tier (cheap cases)
EVERY = ["native", "numpy"]
