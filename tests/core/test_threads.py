"""The thread helpers: every item once, results in order."""

import numpy as np

from nephele.core.threads import split_map, thread_map


def test_split_map_covers_each_index_once_in_order():
    n = 10_007
    hits = np.zeros(n, int)

    def mark(s):
        hits[s] += 1
        return s.start, s.stop

    spans = split_map(mark, n, threads=2, chunk=1000)
    assert np.all(hits == 1)
    assert spans[0][0] == 0 and spans[-1][1] == n
    assert all(a[1] == b[0] for a, b in zip(spans, spans[1:]))


def test_split_map_sums_like_numpy_and_handles_empty():
    x = np.random.default_rng(3).random(300_000)
    assert np.isclose(sum(split_map(lambda s: x[s].sum(), x.size, threads=2)), x.sum(), rtol=1e-12)
    assert split_map(lambda s: 1, 0) == []


def test_thread_map_keeps_order():
    assert thread_map(lambda v: v * v, range(50), 3) == [v * v for v in range(50)]
