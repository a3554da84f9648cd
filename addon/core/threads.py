"""The engine's one small thread pool, for work that spends its time in numpy and lets go of
the GIL (sparse products, gathers, dense products): two tasks run on both cores, and Blender's
main thread stays free meanwhile."""

from __future__ import annotations

import os

_POOL: dict = {}


def parallel_map(fn, items):
    """``map`` over the pool (two threads at most; in order when the machine has one core or
    there is one item). The pool is per process: a process forked after it was made (Blender's
    job children) has none of its threads, so it makes its own. A task run on the pool must not
    itself call ``parallel_map``: it would wait on the pool it holds."""
    workers = min(2, os.cpu_count() or 1)
    if workers < 2 or len(items) < 2:
        return [fn(x) for x in items]
    pid = os.getpid()
    if _POOL.get("pid") != pid:
        from concurrent.futures import ThreadPoolExecutor

        _POOL.clear()
        _POOL.update(pid=pid, pool=ThreadPoolExecutor(workers, thread_name_prefix="brdf_moments-sums"))
    return list(_POOL["pool"].map(fn, items))
