"""Every test here writes GRIB indexes and unpacked zips into a cache of its own, never the user's."""

import pytest


@pytest.fixture(autouse=True)
def _own_cache(own_cache):
    return own_cache
