"""One 2-worker Dask LocalCluster (bpy in each worker) shared by the farm tests that can share it."""

import pytest


@pytest.fixture(scope="session")
def farm_cluster():
    pytest.importorskip("bpy")
    from nephele.farm.cluster import local_cluster

    cluster = local_cluster(workers=2)
    yield cluster
    cluster.close()
