"""``core.edit.blas.one_thread``: OpenBLAS on one thread inside a block, restored after, also when
blocks nest or overlap from two threads (the live preview's thread and an Apply)."""

import threading

import numpy as np

from addon.core.edit import blas


def _threads():
    return [get() for get, _ in blas._openblas()]


def test_this_numpy_uses_an_openblas_the_helper_finds():
    name = np.__config__.CONFIG["Build Dependencies"]["blas"]["name"]
    assert "openblas" in name.lower()  # the pinned numpy 1.26 wheel
    assert blas._openblas(), "OpenBLAS is loaded but its thread setter was not found"


def test_one_thread_inside_restored_after_nested_and_overlapping():
    before = _threads()
    with blas.one_thread():
        assert set(_threads()) == {1}
        entered, leave = threading.Event(), threading.Event()

        def other():
            with blas.one_thread():
                entered.set()
                leave.wait(5)

        t = threading.Thread(target=other)
        t.start()
        assert entered.wait(5)
    # this block has ended, the other thread's has not: still one thread
    assert set(_threads()) == {1}
    leave.set()
    t.join(5)
    assert _threads() == before


def test_results_inside_are_the_same_solve():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(48, 48))
    a = a @ a.T + 48 * np.eye(48)
    b = rng.normal(size=48)
    with blas.one_thread():
        x = np.linalg.solve(a, b)
    np.testing.assert_allclose(a @ x, b, rtol=1e-12, atol=1e-12)
