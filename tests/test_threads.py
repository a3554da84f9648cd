"""The engine's small pool (``core/threads``): work goes to its two threads, except in a thread
that said its cores are taken (the region's), where it runs in order in that thread."""

import os
import threading

import pytest

from addon.core.threads import in_order, keep_in_order, parallel_map


def _where():
    return parallel_map(lambda _: threading.current_thread().name, [0, 1, 2, 3])


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: the pool is never used")
def test_the_pool_runs_the_items_unless_the_thread_keeps_them_in_order():
    here = threading.current_thread().name
    assert all(n.startswith("brdf_moments-sums") for n in _where())
    with in_order():
        assert _where() == [here] * 4
        with in_order():
            assert _where() == [here] * 4
        assert _where() == [here] * 4  # the inner block leaves the outer one's order
    assert all(n.startswith("brdf_moments-sums") for n in _where())

    seen = {}

    def worker():
        keep_in_order()
        seen["names"] = _where()

    t = threading.Thread(target=worker, name="a region thread")
    t.start()
    t.join()
    assert seen["names"] == ["a region thread"] * 4
    assert all(n.startswith("brdf_moments-sums") for n in _where())  # other threads unaffected


def test_results_keep_the_items_order():
    assert parallel_map(lambda x: x * x, list(range(7))) == [x * x for x in range(7)]
    with in_order():
        assert parallel_map(lambda x: x * x, list(range(7))) == [x * x for x in range(7)]
