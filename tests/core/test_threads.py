"""The thread helpers: every item once, results in order."""

import numpy as np
import pytest

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


def test_thread_map_keeps_its_threads_and_runs_on_them():
    import threading

    names = thread_map(lambda v: (threading.get_ident(), threading.current_thread().name), range(40), 2)
    again = thread_map(lambda v: threading.current_thread().name, range(40), 2)
    workers = {n for _, n in names} | set(again)
    assert threading.current_thread().name in workers  # this thread takes items too
    others = workers - {threading.current_thread().name}
    assert len(others) <= 1  # the same kept thread both times, not a new one per call
    assert all(n.startswith("nephele-map") for n in others)


def test_thread_map_inside_thread_map_and_errors():
    assert thread_map(lambda x: sum(thread_map(lambda y: x * y, range(5), 2)), range(6), 2) == [
        10 * x for x in range(6)]

    def bad(x):
        if x == 7:
            raise ValueError("item 7")
        return x

    with pytest.raises(ValueError, match="item 7"):
        thread_map(bad, range(20), 2)
    done = []

    def slow_bad(x):
        import time

        if x == 1:
            raise ValueError("item 1")
        time.sleep(0.01)
        done.append(x)

    with pytest.raises(ValueError, match="item 1"):
        thread_map(slow_bad, range(200), 2)
    assert len(done) < 10  # the other thread stopped taking items
    assert thread_map(lambda v: v + 1, range(5), 2) == [1, 2, 3, 4, 5]  # the pool still works


@pytest.mark.filterwarnings("ignore:This process .* is multi-threaded:DeprecationWarning")
def test_thread_map_in_a_forked_child():  # (a kept pool's threads do not survive a fork: it starts its own)
    import multiprocessing as mp

    thread_map(lambda v: v, range(4), 2)  # the parent's kept pool exists
    ctx = mp.get_context("fork")
    with ctx.Pool(1) as pool:
        assert pool.apply(_child_map) == [0, 2, 4, 6]


def _child_map():
    return thread_map(lambda v: 2 * v, range(4), 2)
