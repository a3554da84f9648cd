"""The engine's one small thread pool, for work that spends its time in numpy and lets go of
the GIL (sparse products, gathers, dense products): two tasks run on both cores, and Blender's
main thread stays free meanwhile."""

from __future__ import annotations

import contextlib
import os
import threading

_POOL: dict = {}
_LOCAL = threading.local()


def parallel_map(fn, items):
    """``map`` over the pool (two threads at most; in order when the machine has one core, there
    is one item, or the calling thread is ``in_order``). The pool is per process: a process
    forked after it was made (Blender's job children) has none of its threads, so it makes its
    own. A task run on the pool must not itself call ``parallel_map``: it would wait on the pool
    it holds."""
    workers = min(2, os.cpu_count() or 1)
    if workers < 2 or len(items) < 2 or getattr(_LOCAL, "in_order", False):
        return [fn(x) for x in items]
    pid = os.getpid()
    if _POOL.get("pid") != pid:
        from concurrent.futures import ThreadPoolExecutor

        _POOL.clear()
        _POOL.update(pid=pid, pool=ThreadPoolExecutor(workers, thread_name_prefix="brdf_moments-sums"))
    return list(_POOL["pool"].map(fn, items))


def keep_in_order():
    """This thread's ``parallel_map`` calls run in order from now on: for the threads of a pool
    that already fills the cores (a pool's ``initializer``)."""
    _LOCAL.in_order = True


@contextlib.contextmanager
def in_order():
    """Within it, this thread's ``parallel_map`` calls run in order: its work already keeps the
    cores busy with threads of its own (the region's), and a second pool beside them only makes
    threads wait for a core (the region 4.1-6.2 s with it, 3.3-5.2 s without, quiet)."""
    was = getattr(_LOCAL, "in_order", False)
    _LOCAL.in_order = True
    try:
        yield
    finally:
        _LOCAL.in_order = was
