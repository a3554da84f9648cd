"""Unregister is safe at any moment (issue 29): register -> unregister -> register with a forked
job, the live preview's work and its timer in flight, under the bpy module (4.5 here, 5.0 in
tests/test_bpy50_lane.py). The same cycle runs in Debian's Blender 3.4 in tests/test_blender_lane.py."""

import os
import sys

import pytest

pytestmark = pytest.mark.blender

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "blender"))


def check_cycle(result):
    """What every lane asserts about tests/blender/cycle.py's result."""
    before, after, again = result["before"], result["after"], result["again"]
    assert result["load"] == ["FINISHED"] and result["preview"] == ["FINISHED"]
    # all of it was really in flight when the add-on was unregistered
    assert before["jobs"] and before["child_alive"] and before["timers"] >= 1
    assert "brdf_moments: live preview" in before["threads"] and "brdf_moments: Cycle" in before["threads"]
    # and the unregister ended all of it: no thread, timer, job or child process is left
    assert after["shutdown"]["left"] == [] and after["threads"] == [] and after["timers"] == 0
    assert not after["live_timer"] and not after["draw_timer"]
    assert after["jobs"] == [] and after["history"] == "unregistered"
    assert not after["child_alive"] and after["child_exitcode"] is not None
    assert after["wm_timers"] == 0 and after["progress_end"]  # the window manager got its timer back
    # nothing finished, nothing posted once unregister began (the draft may come before it)
    assert after["reports"] == [] and after["posted_after"] == 0
    assert not after["property"]
    assert result["unregister_seconds"] < 45
    # registered again, the add-on works
    assert again["property"] and again["load"] == ["FINISHED"] and again["apply"] == ["FINISHED"]


def test_register_unregister_register_with_work_in_flight(blender, sample_table, tmp_path):
    import cycle

    import samples

    sample_table("ggx_glossy")
    module = "bl_ext.bmtest.brdf_moments"
    try:
        result = cycle.run(blender, module, samples.sample_path("ggx_glossy"), str(tmp_path))
    finally:
        import addon_utils

        if not hasattr(blender.types.Material, "brdf_moments"):
            addon_utils.enable(module, default_set=True)
    check_cycle(result)


def test_the_multiprocessing_alias_never_points_at_a_scripts_main(blender):
    """Blender clears a -P script's temporary __main__ when the script ends; multiprocessing's
    alias of it then crashed Blender's exit (addon_utils.disable_all reads every module)."""
    import types

    lifecycle = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.lifecycle"]
    script_main = types.ModuleType("__main__")
    saved = sys.modules["__main__"], sys.modules.get("__mp_main__")
    try:
        sys.modules["__main__"] = sys.modules["__mp_main__"] = script_main  # as `import multiprocessing` in a script
        assert lifecycle.detach_mp_main()
        assert sys.modules["__mp_main__"] is not script_main
        assert getattr(sys.modules["__mp_main__"], "__addon_enabled__", False) is False
    finally:
        sys.modules["__main__"] = saved[0]
        if saved[1] is not None:
            sys.modules["__mp_main__"] = saved[1]


def test_the_timer_book_forgets_timers_that_ran(blender):
    """A slider move registers a new debounce timer each time: the book of timers to stop at
    unregister keeps only those still registered, so a long session does not grow it."""
    lifecycle = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.lifecycle"]
    made = []
    for _ in range(50):

        def once():
            return None

        made.append(once)
        lifecycle.register_timer(once, first_interval=100.0)
    assert set(made) <= set(lifecycle.timers())
    for fn in made:
        blender.app.timers.unregister(fn)  # as if each had run
    last = made[-1]
    lifecycle.register_timer(last, first_interval=100.0)
    assert [f for f in lifecycle._TIMERS if f in made] == [last]
    blender.app.timers.unregister(last)


def test_opening_a_file_ends_the_drawing_threads_first(blender):
    """load_pre: the threads drawing or baking for the file being left are stopped and joined
    before Blender replaces it, and the pictures drawn for it dropped; a job's listener and the
    warm-up (``outlives_file``) go on."""
    import threading

    import numpy as np

    base = "bl_ext.bmtest.brdf_moments.addon.blender."
    lifecycle, icons = sys.modules[base + "lifecycle"], sys.modules[base + "icons"]
    drawing_stop, job_stop = threading.Event(), threading.Event()
    seen = {}

    def drawing():  # as a chart's or the live preview's thread: ends when asked to stop
        drawing_stop.wait(60)
        # (read here only because the main thread is waiting in the join: the file not yet left)
        seen["scene_when_stopped"] = [s.name for s in blender.data.scenes]

    blender.data.scenes.new("Left behind")
    drawer = lifecycle.start_thread(drawing, "test: drawing", stop=drawing_stop.set)
    listener = lifecycle.start_thread(job_stop.wait, "test: job", stop=job_stop.set, args=(60,), outlives_file=True)
    icons.put(icons.thumbnail_key("Left behind"), np.ones((4, 4, 4), np.float32))
    try:
        blender.ops.wm.read_homefile(use_empty=True)
        assert not drawer.is_alive() and "Left behind" in seen["scene_when_stopped"]
        assert listener.is_alive()
        assert icons.icon_id(icons.thumbnail_key("Left behind")) is None
    finally:
        job_stop.set()
        drawing_stop.set()
        listener.join(5)


def test_a_slider_moves_work_runs_on_one_worker_the_latest_first(blender):
    """Slider moves hand their work to one long-lived thread (``LatestWorker``): a move made
    while an older one runs replaces any not yet started, opening a file stops the worker, and
    the next move starts a fresh one."""
    import threading

    lifecycle = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.lifecycle"]
    worker = lifecycle.LatestWorker("test: announce")
    release, ran, threads = threading.Event(), [], []

    def job(tag, wait=False):
        def run():
            if threading.current_thread() not in threads:  # the objects: an ident may be reused
                threads.append(threading.current_thread())
            if wait:
                release.wait(30)
            ran.append(tag)

        return run

    worker.submit(job("first", wait=True))
    for _ in range(200):  # the first is running (and holding the worker) before the others come
        if threads:
            break
        threading.Event().wait(0.01)
    assert worker.busy()  # running "first"
    for tag in ("second", "third", "latest"):
        worker.submit(job(tag))
    release.set()
    for _ in range(300):
        if ran[-1:] == ["latest"] and not worker.busy():
            break
        threading.Event().wait(0.01)
    assert ran == ["first", "latest"] and len(threads) == 1  # the moves in between were dropped
    assert not worker.busy() and threads[0].is_alive()  # idle: its thread waits for the next move
    named = [t for t in lifecycle.threads() if t.name == "test: announce"]
    assert len(named) == 1
    blender.ops.wm.read_homefile(use_empty=True)  # opening a file stops it
    assert not named[0].is_alive()
    worker.submit(job("after"))
    for _ in range(300):
        if ran[-1:] == ["after"]:
            break
        threading.Event().wait(0.01)
    assert ran[-1] == "after" and len(threads) == 2  # a fresh thread served it
    lifecycle.file_loading(timeout=5.0)


def test_threads_started_while_a_file_opens_in_a_window_wait_for_the_operator_to_return(blender):
    """In a window, ``file_loading`` holds back every thread started until the file operator
    has returned (Blender 3.4 crashed when a thread started by the load_post handler ran numpy
    through the end of a script's open_mainfile). A second open before that forgets the held
    threads of the file left, stopping them (so a slider worker serves the next move), and
    keeps the ones that outlive a file; the first timer pass starts them."""
    import threading

    lifecycle = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.lifecycle"]
    ran, stopped = [], []

    def record(tag):
        return lambda: ran.append(tag)

    report = lifecycle.file_loading(timeout=5.0, hold=True)
    try:
        assert report["held"] and blender.app.timers.is_registered(lifecycle._release_held)
        plot = lifecycle.start_thread(record("plot"), "test: plot", stop=lambda: stopped.append("plot"))
        warm = lifecycle.start_thread(record("warm"), "test: warm", outlives_file=True)
        worker = lifecycle.LatestWorker("test: held worker")
        worker.submit(record("move"))
        threading.Event().wait(0.2)
        assert ran == [] and not plot.is_alive() and plot.ident is None  # none of them started
        assert {t.name for t in lifecycle.held_threads()} == {"test: plot", "test: warm", "test: held worker"}
        lifecycle.file_loading(timeout=5.0, hold=True)  # another file before the first was in
        assert stopped == ["plot"] and [t.name for t in lifecycle.held_threads()] == ["test: warm"]
        lifecycle._release_held()  # Blender's first timer pass after the operator
        assert lifecycle.held_threads() == []
        warm.join(5)
        worker.submit(record("next move"))  # the worker held for the left file was stopped: a fresh one
        for _ in range(300):
            if "next move" in ran:
                break
            threading.Event().wait(0.01)
        assert sorted(ran) == ["next move", "warm"] and plot.ident is None
        late = lifecycle.start_thread(record("late"), "test: late")  # released: threads start at once
        late.join(5)
        assert ran[-1] == "late"
    finally:
        lifecycle._release_held()
        if blender.app.timers.is_registered(lifecycle._release_held):
            blender.app.timers.unregister(lifecycle._release_held)
        lifecycle.file_loading(timeout=5.0, hold=False)
