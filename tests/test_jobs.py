"""The job runner behind Analyse and Apply (a child process, or a thread), driven the way Blender drives a modal
operator (timer events, Esc), with stand-ins for the window manager: the bpy module has
no window, so this is where progress, cancel and error reporting are checked."""

import threading
import time

import pytest

pytestmark = pytest.mark.blender  # the job runner in the bpy module


class _WM:
    def __init__(self):
        self.progress, self.timers, self.handlers, self.windows = [], 0, [], [object()]

    def event_timer_add(self, step, window=None):
        self.timers += 1
        return object()

    def event_timer_remove(self, timer):
        self.timers -= 1

    def progress_begin(self, lo, hi):
        self.progress.append(("begin", lo, hi))

    def progress_update(self, value):
        self.progress.append(value)

    def progress_end(self):
        self.progress.append("end")

    def modal_handler_add(self, op):
        self.handlers.append(op)


class _Workspace:
    def __init__(self):
        self.status = []

    def status_text_set(self, text):
        self.status.append(text)


class _Context:
    def __init__(self):
        self.window_manager, self.workspace, self.window = _WM(), _Workspace(), object()


class _Event:
    def __init__(self, type_, value="NOTHING"):
        self.type, self.value = type_, value


@pytest.fixture
def job_class(blender):
    import sys

    jobs = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.jobs"]

    class Job(jobs.BackgroundJob):
        job_label = "Testing"
        use_process = False  # these tests hold the work with threading.Event gates

        def __init__(self, work):
            self.work, self.reports, self.finished_with = work, [], None

        @staticmethod
        def has_window(context):
            return True

        def report(self, level, text):
            self.reports.append((set(level), text))

        def start(self, context):
            return self.work

        def finish(self, context, result):
            self.finished_with = result

    return Job


def _drive(op, ctx, until=10.0, esc_after=None):
    """Send timer events (and an Esc) until the operator leaves the modal state."""
    t0 = time.monotonic()
    sent_esc = False
    while time.monotonic() - t0 < until:
        if esc_after is not None and not sent_esc and esc_after():
            state = op.modal(ctx, _Event("ESC", "PRESS"))
            sent_esc = True
            if state & {"FINISHED", "CANCELLED"}:
                return state
        state = op.modal(ctx, _Event("TIMER"))
        if state & {"FINISHED", "CANCELLED"}:
            return state
        time.sleep(0.01)
    raise AssertionError("the job never finished")


def test_progress_reaches_the_status_bar_and_the_result_is_written_back(job_class):
    gate = threading.Event()

    def work(report_progress):
        for k in range(1, 5):
            report_progress(k, 4)
            if k == 2:
                gate.wait(5)  # hold at 50 % until the test has seen it
        return "done"

    op, ctx = job_class(work), _Context()
    assert op.invoke(ctx, _Event("NONE")) == {"RUNNING_MODAL"}
    assert ctx.window_manager.handlers == [op] and ctx.window_manager.timers == 1
    for _ in range(500):
        op.modal(ctx, _Event("TIMER"))
        if 500 in ctx.window_manager.progress:
            break
        time.sleep(0.01)
    assert 500 in ctx.window_manager.progress
    assert any(s and "Testing 50 %" in s and "Esc to cancel" in s for s in ctx.workspace.status)
    # The status bar is rewritten only when its text changes (each write is a redraw).
    assert len(ctx.workspace.status) < 20 and all(
        a != b for a, b in zip(ctx.workspace.status, ctx.workspace.status[1:])
    )
    gate.set()
    assert _drive(op, ctx) == {"FINISHED"}
    assert op.finished_with == "done"
    assert ctx.window_manager.timers == 0 and ctx.window_manager.progress[-1] == "end"
    assert ctx.workspace.status[-1] is None  # the status bar is given back


def test_every_event_but_esc_passes_through_and_right_click_does_not_cancel(job_class):
    import sys

    jobs = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.jobs"]
    gate = threading.Event()

    def work(report_progress):
        gate.wait(10)
        report_progress(1, 1)
        return "done"

    op, ctx = job_class(work), _Context()
    op._mat_name = "M"
    op.invoke(ctx, _Event("NONE"))
    assert jobs.running() == [("Testing", "M")]
    for kind, value in (
        ("RIGHTMOUSE", "PRESS"),
        ("RIGHTMOUSE", "RELEASE"),
        ("MOUSEMOVE", "NOTHING"),
        ("MIDDLEMOUSE", "PRESS"),
        ("N", "PRESS"),
        ("LEFTMOUSE", "CLICK"),
        ("WHEELUPMOUSE", "PRESS"),
        ("ESC", "RELEASE"),
        ("TIMER", "NOTHING"),
    ):
        assert op.modal(ctx, _Event(kind, value)) == {"PASS_THROUGH"}, kind
    assert not op._cancel.is_set()
    gate.set()
    assert _drive(op, ctx) == {"FINISHED"} and op.finished_with == "done"
    assert jobs.running() == []
    last = jobs.HISTORY[-1]
    assert (last["label"], last["material"], last["outcome"]) == ("Testing", "M", "finished")
    assert last["end"] >= last["start"]


def test_esc_is_consumed_by_the_job(job_class):
    gate = threading.Event()

    def work(report_progress):
        gate.wait(10)
        report_progress(1, 1)

    op, ctx = job_class(work), _Context()
    op.invoke(ctx, _Event("NONE"))
    # Ends at once, without waiting for the worker, and not passed on to the UI.
    assert op.modal(ctx, _Event("ESC", "PRESS")) == {"CANCELLED"}
    assert ctx.window_manager.timers == 0 and ctx.window_manager.progress[-1] == "end"
    assert ctx.workspace.status[-1] is None
    gate.set()
    op._thread.join(5)
    assert not op._thread.is_alive() and op.finished_with is None  # the late result is dropped
    import sys

    assert sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.jobs"].HISTORY[-1]["outcome"] == "cancelled"


def test_esc_cancels_and_changes_nothing(job_class):
    started = threading.Event()

    def work(report_progress):
        started.set()
        for k in range(10_000):
            report_progress(k, 10_000)  # raises once cancelled
            time.sleep(0.001)
        return "should not get here"

    op, ctx = job_class(work), _Context()
    op.invoke(ctx, _Event("NONE"))
    assert _drive(op, ctx, esc_after=started.is_set) == {"CANCELLED"}
    assert op.finished_with is None
    assert op.reports and op.reports[-1][0] == {"WARNING"} and "cancelled" in op.reports[-1][1]
    assert ctx.window_manager.timers == 0
    op._thread.join(2)
    assert not op._thread.is_alive()  # the worker stopped at its next progress report


@pytest.mark.parametrize(
    "exc, expect",
    [(ValueError("x.binary: too short"), "x.binary: too short"), (RuntimeError("boom"), "RuntimeError: boom")],
)
def test_errors_in_the_worker_become_reports(job_class, exc, expect):
    def work(report_progress):
        raise exc

    op, ctx = job_class(work), _Context()
    op.invoke(ctx, _Event("NONE"))
    assert _drive(op, ctx) == {"CANCELLED"}
    assert op.reports == [({"ERROR"}, expect)]
    assert op.finished_with is None


def _gil_holding_work(seconds):
    """A string on which a backtracking regex keeps the GIL for at least ``seconds`` in one C
    call (the re engine never releases it), like the long numpy calls measured in Blender 3.4.
    Each extra "a" doubles the time; measured, not extrapolated, so a loaded machine cannot
    make it short."""
    import re

    for n in range(16, 40):
        t0 = time.perf_counter()
        re.match(r"(a+)+$", "a" * n + "b")
        if time.perf_counter() - t0 >= seconds / 2:
            return "a" * (n + 1) + "b"
    raise AssertionError("the regex never got slow")


def test_a_child_process_runs_the_work_and_its_gil_never_reaches_the_main_loop(job_class):
    import re

    text = _gil_holding_work(1.0)

    def work(report_progress):
        report_progress(1, 4)
        t0 = time.perf_counter()
        re.match(r"(a+)+$", text)  # a second or more holding this process's GIL
        held = time.perf_counter() - t0
        report_progress(3, 4)
        return {"pid": __import__("os").getpid(), "value": 42, "held": held}

    for use_process in (True, False):
        op, ctx = job_class(work), _Context()
        op.use_process = use_process
        gaps, last = [], time.monotonic()  # from before invoke: a thread may take the GIL as it starts
        op.invoke(ctx, _Event("NONE"))
        assert (op._proc is not None) == use_process
        while True:
            state = op.modal(ctx, _Event("TIMER"))
            now = time.monotonic()
            gaps.append(now - last)
            last = now
            if state & {"FINISHED", "CANCELLED"}:
                break
            time.sleep(0.01)
        assert state == {"FINISHED"} and op.finished_with["value"] == 42
        assert op.finished_with["held"] > 0.4  # the work really held the GIL that long
        if use_process:
            assert op.finished_with["pid"] != __import__("os").getpid()
            assert max(gaps) < 0.5, max(gaps)  # the main loop ran all along
            assert 250 in ctx.window_manager.progress  # progress crossed the process boundary
        else:
            # The same work in a thread stalls it: the check above can fail.
            assert max(gaps) > 0.5 * op.finished_with["held"], (max(gaps), op.finished_with["held"])


def test_esc_kills_the_child_at_once_and_errors_come_back_as_reports(job_class):
    def sleeper(report_progress):
        report_progress(1, 2)
        time.sleep(60)
        return "late"

    op, ctx = job_class(sleeper), _Context()
    op.use_process = True
    op.invoke(ctx, _Event("NONE"))
    time.sleep(0.3)
    t0 = time.monotonic()
    assert op.modal(ctx, _Event("ESC", "PRESS")) == {"CANCELLED"}
    op._thread.join(5)
    assert not op._proc.is_alive() and time.monotonic() - t0 < 5 and op.finished_with is None

    def broken(report_progress):
        raise ValueError("x.binary: too short")

    op, ctx = job_class(broken), _Context()
    op.use_process = True
    op.invoke(ctx, _Event("NONE"))
    assert _drive(op, ctx) == {"CANCELLED"} and op.reports == [({"ERROR"}, "x.binary: too short")]

    def dies(report_progress):
        __import__("os")._exit(3)

    op, ctx = job_class(dies), _Context()
    op.use_process = True
    op.invoke(ctx, _Event("NONE"))
    assert _drive(op, ctx) == {"CANCELLED"}
    assert op.reports == [({"ERROR"}, "the worker process ended without a result (exit code 3)")]


def test_a_large_result_comes_back_whole_with_its_arrays_out_of_band(job_class):
    """Build Preview returns two MERL tables (~100 MB): they come back through the pipe as
    out-of-band buffers (pickle protocol 5), every kind of array intact."""
    import numpy as np

    rng = np.random.default_rng(7)
    big = rng.standard_normal((3, 1_458_000))  # one MERL table's worth of float64
    strided = rng.standard_normal((50, 40))[:, ::3]  # not contiguous: pickled in band
    parts = {
        "big": big,
        "f32": big[0].astype(np.float32),
        "strided": strided,
        "empty": np.zeros((0, 3)),
        "mask": big[1] > 0,
        "scalar": np.float64(2.5),
        "text": "kd",
        "nested": [big[2, :5], (1, 2)],
    }

    def work(report_progress):
        report_progress(1, 2)
        return parts

    op, ctx = job_class(work), _Context()
    op.use_process = True
    op.invoke(ctx, _Event("NONE"))
    assert _drive(op, ctx, until=60) == {"FINISHED"}
    got = op.finished_with
    assert set(got) == set(parts)
    for key in ("big", "f32", "strided", "empty", "mask"):
        assert got[key].dtype == parts[key].dtype and got[key].shape == parts[key].shape, key
        assert np.array_equal(got[key], parts[key]), key
    got["big"][0, 0] = 1.0  # the parent owns writable arrays
    assert got["scalar"] == 2.5 and got["text"] == "kd" and np.array_equal(got["nested"][0], big[2, :5])
    assert got["nested"][1] == (1, 2)
