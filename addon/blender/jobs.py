"""Long work (analysis, re-synthesis) off Blender's main thread, with progress and cancel.

An operator that mixes in ``BackgroundJob`` defines ``start(context)`` (main thread: read
the UI state, return a function of ``report_progress`` that does the work with no bpy in
it) and ``finish(context, result)`` (main thread again: write the result back).

- With a window (the UI), ``invoke`` runs the work in a forked child process on Linux (a
  thread elsewhere), shows progress in the status bar and the window's progress
  cursor, and Esc cancels it at once. Every other event passes through, so the artist can
  orbit, click and use the panels while a job runs. A process, not a thread: numpy calls
  that hold the GIL (measured up to 1.3 s in Blender 3.4's window) then cannot stall
  Blender's main loop, and Esc stops the work outright instead of at its next progress.
- Without one (``blender -b``, the bpy module, ``execute`` from a script), the same work
  runs in place, so every operator also works headless.

Errors never reach the user as a traceback: bad input becomes an ERROR report and the
operator returns CANCELLED.
"""

from __future__ import annotations

import sys
import threading
import time

import bpy

from . import lifecycle


class Cancelled(Exception):
    """Raised inside the work when the user cancelled it."""


# The jobs running now, by operator instance: (label, material name). Read by ``running``.
_RUNNING: dict = {}
# The last jobs that ended: label, material, outcome (finished/cancelled/failed), start and
# end on time.monotonic(); the windowed test lane reads it to time the main loop per job.
HISTORY: list = []


# The same jobs as unregister sees them: stop (cancel, kill the child), the window manager,
# its timer and the workspace whose status bar the job writes.
_LIVE: dict = {}


@lifecycle.on_shutdown
def cancel_all():
    """End every running job at once (unregister): its work cancelled, its child process killed,
    its timer and progress given back; nothing it would have written is written."""
    for key, job in list(_LIVE.items()):
        _LIVE.pop(key, None)
        job["stop"]()
        label, mat = _RUNNING.pop(key, ("", ""))
        now = time.monotonic()
        HISTORY.append(
            {
                "label": label,
                "material": mat,
                "outcome": "unregistered",
                "start": job["started"],
                "end": now,
                "marks": [],
            }
        )
        for step in (
            lambda: job["wm"].event_timer_remove(job["timer"]),
            job["wm"].progress_end,
            lambda: job["workspace"] is not None and job["workspace"].status_text_set(None),
        ):
            try:
                step()
            except (ReferenceError, RuntimeError, AttributeError, TypeError):
                pass  # the window is gone already (Blender is quitting)
    del HISTORY[:-50]


def running() -> list:
    """(label, material) of each job in progress, oldest first (the panel and tests use it)."""
    return list(_RUNNING.values())


def _ended(op, outcome):
    label, mat = _RUNNING.pop(id(op), (op.job_label, ""))
    HISTORY.append(
        {
            "label": label,
            "material": mat,
            "outcome": outcome,
            "start": op._started,
            "end": time.monotonic(),
            "marks": list(getattr(op, "_marks", ())),
        }
    )
    del HISTORY[:-50]


def warm_up(theta_o):
    """Build in a thread what every edit of these views shares (``core.edit.solve.warm``), so
    that the first slider move, and each Apply's forked child, find it ready (~1 s cold).
    Nothing to gain without a window: there, work runs in place and builds it once anyway."""
    if bpy.app.background:
        return
    from ..core.edit.solve import warm

    lifecycle.start_thread(warm, "brdf_moments: warm-up", args=(list(theta_o),), outlives_file=True)


# Errors that mean "this input or these sliders cannot be used", reported in one line.
USER_ERRORS = (OSError, ValueError, MemoryError, ArithmeticError)


def _message(exc) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0]


def _error_text(exc) -> str:
    return _message(exc) if isinstance(exc, USER_ERRORS) else f"{type(exc).__name__}: {_message(exc)}"


def _in_child(work, conn):
    """The child process: run the work, send progress (when it changes) and the result."""
    last = None

    def report_progress(done, total):
        nonlocal last
        if (done, total) != last:
            last = (done, total)
            conn.send(("progress", done, total))

    from ..core.file.safeio import run_scope

    try:
        with run_scope():  # the inputs this job reads are what its writes may not replace
            message = ("result", work(report_progress))
    except BaseException as exc:  # noqa: BLE001 - sent to the parent, reported there
        message = ("error", _error_text(exc))
    try:
        send_large(conn, message)
    except Exception as exc:  # noqa: BLE001 - e.g. a result that does not pickle
        send_large(conn, ("error", f"{type(exc).__name__}: {_message(exc)}"))
    conn.close()


# A result can hold whole tables (Build Preview's two MERL tables: ~100 MB). Unpickled in one
# piece in the parent, that copies every array while holding the GIL (0.3-0.4 s measured under
# load, a frozen Blender). Pickle protocol 5 sends the arrays' memory out of band: the
# listening thread reads each buffer into its own bytearray (os reads, GIL released) and the
# unpickle then only wraps them, so its cost no longer grows with the result's size.
_LARGE = "large-v1"


# Each buffer travels in pieces of at most CHUNK bytes, received into a preallocated array: a
# receive copies its whole message while holding the GIL (multiprocessing reads a message into
# a BytesIO, then copies it out), and a zeroed bytearray of the whole size is another pass under
# the GIL: with 50 MB buffers the windowed lane saw the listening thread hold it for 0.3-0.4 s.
CHUNK = 1 << 22


def send_large(conn, message):
    import pickle

    buffers = []
    head = pickle.dumps(message, protocol=5, buffer_callback=buffers.append)
    raws = [b.raw() for b in buffers]
    conn.send((_LARGE, len(head), [r.nbytes for r in raws]))
    conn.send_bytes(head)
    for raw in raws:
        for offset in range(0, raw.nbytes, CHUNK):
            conn.send_bytes(raw, offset, min(CHUNK, raw.nbytes - offset))


def recv_message(conn):
    """The next message from the child: progress tuples as sent, large ones reassembled."""
    import pickle

    import numpy as np

    message = conn.recv()
    if not (isinstance(message, tuple) and message and message[0] == _LARGE):
        return message
    _, head_size, sizes = message
    head = conn.recv_bytes(max(head_size, 1))
    buffers = []
    for size in sizes:
        buf = np.empty(size, np.uint8)  # not zeroed: every byte is received into it
        done = 0
        while done < size:
            got = conn.recv_bytes_into(buf, done)
            if got == 0 or got > CHUNK:
                raise EOFError("a result buffer arrived in a wrong piece")
            done += got
        buffers.append(buf)
    return pickle.loads(head, buffers=buffers)


def _fork_context():
    # Linux only: macOS has fork but its system frameworks are not fork-safe, Windows has none.
    if not sys.platform.startswith("linux"):
        return None
    try:
        return lifecycle.import_multiprocessing().get_context("fork")
    except ValueError:
        return None


class BackgroundJob:
    job_label = "Working"
    use_process = True  # with a window: the work in a child process where the platform forks

    # --- to be defined by the operator ------------------------------------------------------
    def start(self, context):  # pragma: no cover - interface
        raise NotImplementedError

    def finish(self, context, result):  # pragma: no cover - interface
        raise NotImplementedError

    def ended(self, context, outcome):
        """Called once a windowed job ends ('finished', 'cancelled' or 'failed'): an operator
        undoes here what its start did for the job's sake."""

    # --- runner -----------------------------------------------------------------------------
    def _prepare(self, context):
        try:
            return self.start(context)
        except USER_ERRORS as exc:
            self.report({"ERROR"}, _message(exc))
            return None

    def _complete(self, context, result):
        try:
            self.finish(context, result)
        except USER_ERRORS as exc:
            self.report({"ERROR"}, _message(exc))
            return {"CANCELLED"}
        return {"FINISHED"}

    def execute(self, context):
        from ..core.file.safeio import run_scope

        work = self._prepare(context)
        if work is None:
            return {"CANCELLED"}
        try:
            with run_scope():  # the files this work reads are never written over by it
                result = work(lambda done, total: None)
        except USER_ERRORS as exc:
            self.report({"ERROR"}, _message(exc))
            return {"CANCELLED"}
        return self._complete(context, result)

    @staticmethod
    def has_window(context) -> bool:
        wm = context.window_manager
        return not bpy.app.background and wm is not None and bool(wm.windows) and context.window is not None

    def invoke(self, context, event):
        if not self.has_window(context):
            return self.execute(context)
        work = self._prepare(context)
        if work is None:
            return {"CANCELLED"}
        # The worker sees only these two plain objects, never the operator: an operator is
        # Blender data (not to be touched off the main thread) and is freed once it ends.
        cancel = self._cancel = threading.Event()
        state = self._state = {"done": 0, "total": 1, "result": None, "error": None, "finished": False}

        marks = self._marks = []  # (time, done, total) per progress report: the job's phases

        def report_progress(done, total):
            if cancel.is_set():
                raise Cancelled()
            state["done"], state["total"] = done, max(total, 1)
            marks.append((time.monotonic(), done, total))

        def run():
            from ..core.file.safeio import run_scope

            try:
                with run_scope():
                    state["result"] = work(report_progress)
            except Cancelled:
                state["error"] = "cancelled"
            except BaseException as exc:  # noqa: BLE001 - reported on the main thread
                state["error"] = _error_text(exc)
            finally:
                state["finished"] = True

        self._proc = None
        fork = _fork_context() if self.use_process else None
        if fork is not None:
            receiver, sender = fork.Pipe(duplex=False)
            proc = self._proc = fork.Process(
                target=_in_child, args=(work, sender), daemon=True, name=f"brdf_moments: {self.job_label}"
            )
            proc.start()
            sender.close()

            def run():  # noqa: F811 - the thread only listens to the child
                try:
                    while True:
                        kind, *rest = recv_message(receiver)
                        if kind == "progress":
                            state["done"], state["total"] = rest[0], max(rest[1], 1)
                            marks.append((time.monotonic(), rest[0], rest[1]))
                        else:
                            state["result" if kind == "result" else "error"] = rest[0]
                            break
                except (EOFError, OSError):
                    proc.join(5)
                    if not cancel.is_set():
                        state["error"] = f"the worker process ended without a result (exit code {proc.exitcode})"
                finally:
                    receiver.close()
                    proc.join(5)
                    state["finished"] = True

        _RUNNING[id(self)] = (self.job_label, getattr(self, "_mat_name", ""))
        self._started = time.monotonic()
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.progress_begin(0, 1000)
        wm.modal_handler_add(self)
        proc = self._proc

        def stop():
            cancel.set()
            if proc is not None:
                proc.kill()  # the listening thread then reads EOF and ends

        # What unregister needs to end this job without the operator (Blender frees a running
        # modal operator when its class is unregistered): plain objects only.
        _LIVE[id(self)] = {
            "stop": stop,
            "wm": wm,
            "timer": self._timer,
            "workspace": context.workspace,
            "started": self._started,
        }
        self._thread = lifecycle.start_thread(run, f"brdf_moments: {self.job_label}", stop=stop, outlives_file=True)
        return {"RUNNING_MODAL"}

    def _end(self, context, outcome):
        _ended(self, outcome)
        _LIVE.pop(id(self), None)
        self.ended(context, outcome)
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)

    def modal(self, context, event):
        # Esc is the job's own key; everything else (mouse, keys, other timers) goes on to the
        # UI, so a job never takes the window from the artist.
        if event.type == "ESC" and event.value == "PRESS":
            # Done at once: the worker stops at its next progress report and its result is
            # dropped (finish never runs), so the material is exactly as it was.
            self._cancel.set()
            if self._proc is not None:
                self._proc.kill()  # the listening thread reaps it
            self._end(context, "cancelled")
            self.report({"WARNING"}, f"{self.job_label}: cancelled, nothing was changed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        st = self._state
        if not st["finished"]:
            frac = st["done"] / st["total"]
            context.window_manager.progress_update(int(1000 * frac))
            if context.workspace is not None:
                text = f"BRDF Moments: {self.job_label} {100 * frac:.0f} % - Esc to cancel"
                # Only when it reads differently (the percentage, a handful of times a job): each
                # call redraws the status bar, a frame of 0.15 s and more on a software-GL
                # display, taken from the job's CPU (a seconds counter made it once a second).
                if text != getattr(self, "_status", None):
                    self._status = text
                    context.workspace.status_text_set(text)
            return {"PASS_THROUGH"}  # other modal operators' timers too
        if st["error"] == "cancelled":  # not reached from the UI (Esc ends at once); kept for safety
            self._end(context, "cancelled")
            self.report({"WARNING"}, f"{self.job_label}: cancelled, nothing was changed")
            return {"CANCELLED"}
        if st["error"]:
            self._end(context, "failed")
            self.report({"ERROR"}, st["error"])
            return {"CANCELLED"}
        done = self._complete(context, st["result"])
        self._end(context, "finished" if done == {"FINISHED"} else "failed")  # after finish: its time counts
        return done
