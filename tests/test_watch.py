"""The windowed lane's watcher (tests/_watch.py), on stand-in processes instead of Blender: a
crash fails at once, with its report, even when a child the crashed process left behind holds
the output open or the crashed process does not exit; nothing of the group outlives the run."""

import os
import sys
import time

from _watch import crash_report, run_watched

CRASH_WITH_CHILD = """
import faulthandler, os, signal, subprocess, sys, threading, time
faulthandler.enable(file=open(sys.argv[1], "w"), all_threads=True)
child = subprocess.Popen(["sleep", "600"])  # inherits the output, as a job's process would
open(sys.argv[2], "w").write(str(child.pid))
threading.Thread(target=time.sleep, args=(600,), name="drawing", daemon=True).start()
time.sleep(0.2)
os.kill(os.getpid(), signal.SIGSEGV)
"""

REPORT_THEN_HANG = """
import sys, time
open(sys.argv[1], "w").write("Blender 3.4 crash: backtrace here")
time.sleep(600)
"""


def _gone(pid):
    """No such process, or only a zombie waiting for its reaper."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            return any(line.split()[:2] == ["State:", "Z"] for line in fh)
    except FileNotFoundError:
        return True


def test_a_crash_with_a_child_holding_the_output_fails_at_once(tmp_path):
    faults, child_pid = tmp_path / "faulthandler.txt", tmp_path / "child.pid"
    crash_dir = tmp_path / "tmp"
    crash_dir.mkdir()
    start = time.monotonic()
    code, why = run_watched(
        [sys.executable, "-c", CRASH_WITH_CHILD, str(faults), str(child_pid)],
        dict(os.environ),
        tmp_path / "log",
        [faults],
        crash_dir,
        timeout=300,
        poll=0.1,
    )
    assert time.monotonic() - start < 30
    assert code == -11 and why.startswith("crashed"), (code, why)
    assert _gone(int(child_pid.read_text()))  # the group was killed: the sleeping child too
    report = crash_report(faults, crash_dir)
    assert "Segmentation fault" in report and 'File "<string>", line 8' in report, report


def test_a_crash_report_then_a_hang_is_stopped_after_the_grace(tmp_path):
    crash_dir = tmp_path / "tmp"
    crash_dir.mkdir()
    start = time.monotonic()
    code, why = run_watched(
        [sys.executable, "-c", REPORT_THEN_HANG, str(crash_dir / "untitled.crash.txt")],
        dict(os.environ),
        tmp_path / "log",
        [tmp_path / "faulthandler.txt"],
        crash_dir,
        timeout=300,
        grace=1.0,
        poll=0.1,
    )
    assert time.monotonic() - start < 15
    assert "still running" in why and code != 0, (code, why)
    assert "--- untitled.crash.txt\nBlender 3.4 crash: backtrace here" in crash_report(tmp_path / "none", crash_dir)


def test_a_clean_run_and_a_timeout(tmp_path):
    crash_dir = tmp_path / "tmp"
    crash_dir.mkdir()
    args = (dict(os.environ), tmp_path / "log", [tmp_path / "faulthandler.txt"], crash_dir)
    code, why = run_watched([sys.executable, "-c", "print('fine')"], *args, timeout=60, poll=0.1)
    assert (code, why) == (0, None)
    assert (tmp_path / "log").read_text() == "fine\n"
    assert crash_report(tmp_path / "faulthandler.txt", crash_dir) == ""
    start = time.monotonic()
    code, why = run_watched(["sleep", "600"], *args, timeout=1.0, poll=0.1)
    assert why == "ran past 1.0 s: stopped" and code == -15 and time.monotonic() - start < 10
