"""BLAS on one thread for work made of many tiny dense products (the edit's Gauss-Newton solve).

OpenBLAS hands even a 48 x 48 solve to its thread pool. When the cores are busy (a test suite, or
Blender drawing in software GL beside an Apply) each hand-off waits for a core: 5-10 ms per solve
measured here, against 20 us on one thread. ``one_thread()`` sets OpenBLAS to one thread for a
block and restores it after; nested or concurrent blocks (the live preview's thread and an edit)
share one count, so the first to enter saves the setting and the last to leave restores it. Where
no OpenBLAS is loaded (another BLAS, another platform) it does nothing.

The count is changed at run time through OpenBLAS's public setter, the way threadpoolctl does
it; the setting is process-wide, so BLAS work in other threads during the block runs on one
thread too (in Blender that is the add-on's own threads: a plot being drawn, the live preview).
"""

from __future__ import annotations

import ctypes
import os
import threading
from contextlib import contextmanager

_LOCK = threading.Lock()
_STATE = {"depth": 0, "saved": None}
_API: list = []  # [(get, set)] per loaded OpenBLAS, found once


def _openblas():
    """(get_num_threads, set_num_threads) of each OpenBLAS this process has loaded."""
    if _API:
        return _API[0]
    found = []
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({line.split()[-1] for line in fh if "openblas" in line.lower() and "/" in line})
    except OSError:
        paths = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path, mode=getattr(os, "RTLD_NOLOAD", 0))  # only one already loaded
        except OSError:
            continue
        for suffix in ("", "64_"):
            get = getattr(lib, f"openblas_get_num_threads{suffix}", None)
            put = getattr(lib, f"openblas_set_num_threads{suffix}", None)
            if get is not None and put is not None:
                get.restype, put.argtypes = ctypes.c_int, [ctypes.c_int]
                found.append((get, put))
                break
    _API.append(found)
    return found


@contextmanager
def one_thread():
    with _LOCK:
        if _STATE["depth"] == 0:
            apis = _openblas()
            _STATE["saved"] = [(put, get()) for get, put in apis]
            for put, _ in _STATE["saved"]:
                put(1)
        _STATE["depth"] += 1
    try:
        yield
    finally:
        with _LOCK:
            _STATE["depth"] -= 1
            if _STATE["depth"] == 0:
                for put, n in _STATE["saved"] or ():
                    put(n)
                _STATE["saved"] = None
