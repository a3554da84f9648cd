"""Everything the add-on leaves running between two events, and how unregister stops it.

Unregister must be safe at any moment: during a job, while the live preview or a plot is
being drawn in a thread, after Build Preview, and at Blender's exit (``addon_utils.disable_all``).
So every thread and timer the add-on starts goes through here:

- ``start_thread(target, name, stop)`` runs ``target`` in a daemon thread and remembers it with
  ``stop``, a function that asks it to end early (a job's cancel, the live preview's newer
  generation). ``shutdown`` calls each ``stop``, then joins the threads (bounded).
- ``register_timer(fn, first_interval)`` registers a ``bpy.app.timers`` function and remembers
  it; ``shutdown`` unregisters the ones still registered, so no callback of an unregistered
  add-on ever runs (it would reach for ``Material.brdf_moments``, which is gone).
- ``on_shutdown(fn)`` adds a clean-up step (the job runner cancels its jobs and kills their
  child processes, gives their window-manager timers and progress back).
- ``file_loading`` runs before another file is opened (a ``load_pre`` handler): the
  ``on_file_load(fn)`` steps drop what was drawn for this file, then the threads drawing or
  baking for it are ended and joined, so none is at work while Blender replaces the file.
  In a window it also holds back every thread started from then on (the ``load_post``
  handler's plots and warm-up): they start at the first timer pass, once the file operator
  has returned. Blender 3.4 in a window crashes when a thread runs numpy while a script's
  ``bpy.ops.wm.open_mainfile`` or ``save_as_mainfile`` is under way (measured with
  ``tests/windowed/thread_during_file_ops.py``: each of 6 runs crashed by its 7th open;
  through the File menu 45 opens did not, nor 60 headless).
  The symptom, "returned NULL without setting an exception", is that of a thread state
  released by the wrong thread: 3.4's ``BPY_thread_save`` releases the GIL of whichever
  thread holds it, where later versions first check that the caller holds it. A thread
  started in ``load_post`` was still running when that operator returned, on every reopen.

``import_multiprocessing`` is the other half. Importing ``multiprocessing`` aliases
``sys.modules['__mp_main__']`` to the ``__main__`` of the moment. Inside a script run by
``blender -P`` (or the Text Editor) that is a temporary module, and when the script ends Blender
(3.4 to 5.0, ``PYMODULE_CLEAR_WORKAROUND`` in ``bpy_interface_run.cc``) sets its dictionary to
NULL and keeps the module object. At exit ``addon_utils.disable_all`` reads an attribute of every
module in ``sys.modules``; on that one the lookup of ``__getattr__`` dereferences the NULL
dictionary: the segmentation fault after ``blender -b -P samples/demo.py`` (exit code 139). The
alias is only used by processes that ``spawn``; the add-on forks. So the alias is pointed at a
module of its own, which lives as long as the process.
"""

from __future__ import annotations

import sys
import threading
import time
import types

_THREADS: list = []  # (thread, stop or None)
_TIMERS: list = []  # functions registered with bpy.app.timers
_CLEANUPS: list = []  # functions run by shutdown, in order
_FILE_STEPS: list = []  # functions run by file_loading, in order
_HELD: list = []  # threads started while a file is being opened, started by _release_held
_HOLD = {"on": False}  # set by file_loading in a window, cleared by _release_held
_LOCK = threading.Lock()
# A module of our own for multiprocessing's alias of __main__ (see the module's docstring).
_MP_MAIN = types.ModuleType("__mp_main__")


def _module_dict(mod):
    """A module's dictionary read through the type's descriptor: None when Blender cleared it,
    without the attribute lookup that would dereference it."""
    try:
        return types.ModuleType.__dict__["__dict__"].__get__(mod)
    except (TypeError, AttributeError):
        return None


def detach_mp_main() -> bool:
    """Point ``__mp_main__`` away from a script's temporary ``__main__``; True if it changed."""
    alias = sys.modules.get("__mp_main__")
    if alias is None or alias is _MP_MAIN:
        return False
    if isinstance(alias, types.ModuleType) and _module_dict(alias) is not None:
        # Alive now; but if it is the __main__ of a script running at this moment, it dies
        # with that script. Blender's own __main__ outlives us either way, so take ours.
        if alias is not sys.modules.get("__main__"):
            return False
    sys.modules["__mp_main__"] = _MP_MAIN
    return True


def import_multiprocessing():
    """``multiprocessing``, imported so that it leaves no alias to a temporary ``__main__``."""
    import multiprocessing

    detach_mp_main()
    return multiprocessing


# --- threads and timers ----------------------------------------------------------------------


def start_thread(target, name, stop=None, args=(), outlives_file=False) -> threading.Thread:
    """``target`` in a daemon thread. It must not call into Blender (bpy, even ``bpy.app.timers``):
    it hands its result to a timer registered from the main thread. ``outlives_file``: it may
    go on while another file is opened (a job's listener, the warm-up: their results belong to
    no file); the others are ended first (``file_loading``)."""
    thread = threading.Thread(target=target, args=args, name=name, daemon=True)
    thread.brdf_moments_outlives_file = outlives_file
    with _LOCK:
        _THREADS[:] = [(t, s) for t, s in _THREADS if t.is_alive() or _is_held(t)]
        _THREADS.append((thread, stop))
        held = _HOLD["on"]
        if held:
            _HELD.append(thread)  # started once the file is open (see the module's docstring)
    if not held:
        thread.start()
    return thread


def _is_held(thread) -> bool:
    return any(t is thread for t in _HELD)


def _forget_held(which) -> list:
    """Drop the held threads ``which(thread)`` picks (with ``_LOCK`` held); returns their
    (thread, stop) pairs. Never started, they are forgotten, but their ``stop`` is still
    called: a ``LatestWorker`` starts a new thread only once its last one was stopped."""
    dropped = [t for t in _HELD if which(t)]
    _HELD[:] = [t for t in _HELD if not which(t)]
    pairs = [(t, s) for t, s in _THREADS if any(t is d for d in dropped)]
    _THREADS[:] = [(t, s) for t, s in _THREADS if not any(t is d for d in dropped)]
    return pairs


def held_threads() -> list:
    """Threads waiting for the file being opened to be in place."""
    with _LOCK:
        return list(_HELD)


def _release_held():
    """The first timer pass after a file was opened: the threads held back start now."""
    with _LOCK:
        _HOLD["on"] = False
        held, _HELD[:] = list(_HELD), []
    for thread in held:
        thread.start()
    return None


class LatestWorker:
    """One daemon thread that runs the latest job handed to it (a job not started when a newer
    one comes is dropped). A slider move hands its work here instead of starting a thread:
    ``Thread.start`` waits until the new thread runs, which under load, with the live preview's
    numpy holding the GIL, kept the main thread 0.2 s (the windowed lane's slider moves)."""

    def __init__(self, name):
        self.name = name
        self._cond = threading.Condition()
        self._job = None
        self._token = None  # the running thread's; stopped by file_loading and shutdown
        self._running = False

    def submit(self, fn):
        with self._cond:
            self._job = fn
            fresh = self._token is None or self._token["stopped"]
            if fresh:
                self._token = {"stopped": False}
            token = self._token
            self._cond.notify_all()
        if fresh:
            start_thread(self._run, self.name, stop=lambda: self._stop(token), args=(token,))

    def _stop(self, token):
        with self._cond:
            token["stopped"] = True
            if self._token is token:
                self._job = None
            self._cond.notify_all()

    def _run(self, token):
        while True:
            with self._cond:
                while not token["stopped"] and self._job is None:
                    self._cond.wait()
                if token["stopped"]:
                    return
                fn, self._job = self._job, None
                self._running = True
            try:
                fn()
            except Exception as exc:  # noqa: BLE001 - the worker serves the next move
                print(f"BRDF Moments: {self.name}: {type(exc).__name__}: {exc}")
            finally:
                with self._cond:
                    self._running = False

    def busy(self) -> bool:
        """A job waiting or running (else its thread, if any, waits on a lock, running no Python)."""
        with self._cond:
            return self._running or self._job is not None


def threads() -> list:
    """The add-on's threads still alive."""
    with _LOCK:
        return [t for t, _ in _THREADS if t.is_alive()]


def register_timer(fn, first_interval=0.0, persistent=False):
    import bpy

    if not bpy.app.timers.is_registered(fn):
        bpy.app.timers.register(fn, first_interval=first_interval, persistent=persistent)
    with _LOCK:
        # a slider move registers a new debounce function each time: forget the ones that ran
        _TIMERS[:] = [f for f in _TIMERS if f is fn or bpy.app.timers.is_registered(f)]
        if fn not in _TIMERS:
            _TIMERS.append(fn)


def timers() -> list:
    """The add-on's timer functions still registered."""
    import bpy

    with _LOCK:
        return [fn for fn in _TIMERS if bpy.app.timers.is_registered(fn)]


def on_shutdown(fn):
    if fn not in _CLEANUPS:
        _CLEANUPS.append(fn)
    return fn


def on_file_load(fn):
    """``fn`` runs before another file is opened, ahead of the threads being ended."""
    if fn not in _FILE_STEPS:
        _FILE_STEPS.append(fn)
    return fn


def _run_steps(steps, when) -> int:
    """Call each step; one failing is printed and does not stop the others. Returns how many ran."""
    done = 0
    for fn in list(steps):
        try:
            fn()
            done += 1
        except Exception as exc:  # noqa: BLE001 - one failing step must not stop the others
            print(f"BRDF Moments: {when}: {type(exc).__name__}: {exc}")
    return done


def _stop_and_join(threads, timeout, when, report):
    """Ask every live thread of ``threads`` ((thread, stop) pairs) to stop, then join them,
    ``timeout`` seconds in all; counts them and names the ones still running in ``report``."""
    for thread, stop in threads:
        if stop is not None and (thread.is_alive() or thread.ident is None):  # running, or held
            try:
                stop()
            except Exception as exc:  # noqa: BLE001
                print(f"BRDF Moments: {when}: stopping {thread.name}: {type(exc).__name__}: {exc}")
    live = [(t, s) for t, s in threads if t.is_alive()]
    deadline = time.monotonic() + timeout
    for thread, _ in live:
        report["threads"] += 1
        thread.join(max(deadline - time.monotonic(), 0.0))
        if thread.is_alive():
            report["left"].append(thread.name)
    if report["left"]:
        print(f"BRDF Moments: {when}: still running after {timeout:.0f} s: {', '.join(report['left'])}")


def file_loading(timeout=5.0, hold=None) -> dict:
    """Before another file is opened (``load_pre``): what the add-on drew or baked for this file
    is dropped (the ``on_file_load`` steps make every thread's result stale and clear what
    waits to be placed), then its threads are asked to stop and joined, ``timeout`` seconds in
    all, so that none is still working while Blender frees this file's data and reads the next.
    A job's listener and the warm-up go on (``outlives_file``). ``hold`` (default: in a window)
    keeps the threads started from now on from running until the operator has returned
    (``_release_held``). Without a window there is no event loop to release them, and Blender
    run headless was measured safe (60 opens with a numpy thread started in each load_post).
    Returns what it found."""
    if hold is None:
        import bpy

        hold = not bpy.app.background
    report = {"steps": _run_steps(_FILE_STEPS, "opening a file"), "threads": 0, "left": [], "held": hold}
    with _LOCK:
        forgotten = _forget_held(lambda t: not t.brdf_moments_outlives_file)
        ending = [(t, s) for t, s in _THREADS if not t.brdf_moments_outlives_file]
        if hold:
            _HOLD["on"] = True
    _stop_and_join(forgotten + ending, timeout, "opening a file", report)
    if hold:
        # Persistent: opening a file drops the other timers. It runs once the operator has
        # returned to Blender's event loop, also when the file could not be read.
        register_timer(_release_held, first_interval=0.0, persistent=True)
    return report


def shutdown(timeout=30.0) -> dict:
    """Stop everything the add-on runs: clean-up steps, timers, then threads (each asked to
    stop, then joined, ``timeout`` seconds in all). Returns what it found, for tests and logs.

    A stopped thread ends at its next check: a job's child is killed at once, the live preview
    stops between Gauss-Newton steps, but the edit's first set-up (about 1 s cold on a quiet
    machine) is not interruptible and took over 10 s with the two cores shared four ways."""
    import bpy

    report = {"cleanups": _run_steps(_CLEANUPS, "unregister"), "timers": 0, "threads": 0, "left": []}
    with _LOCK:
        registered, _TIMERS[:] = list(_TIMERS), []
        running = _forget_held(lambda t: True) + list(_THREADS)
        _THREADS[:] = []
        _HOLD["on"] = False
    for fn in registered:
        if bpy.app.timers.is_registered(fn):
            bpy.app.timers.unregister(fn)
            report["timers"] += 1
    _stop_and_join(running, timeout, "unregister", report)
    detach_mp_main()
    return report
