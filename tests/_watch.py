"""Running Blender so that a crash fails a test at once instead of hanging it: its own process
group, its output into a file (not a pipe that a surviving child would hold open), the group
killed at the end, and the crash reports gathered (Blender's ``*.crash.txt``, which shows the
main thread only, and Python's faulthandler, which shows every Python thread)."""

import os
import signal
import subprocess
import time

GRACE = 20  # seconds Blender gets to exit by itself once it has reported a crash


def _alive_in_group(pgid):
    """Whether a process of group ``pgid`` still runs (zombies, which wait for a reaper, do not)."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()  # after the command's name
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            return True
    return False


def _group_kill(pid):
    """Ends the process group ``pid`` leads (xvfb-run, Xvfb, Blender, the jobs' children):
    SIGTERM, then SIGKILL for whatever is left after 5 s."""
    for sig, wait in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 0.0)):
        try:
            os.killpg(pid, sig)
        except ProcessLookupError:
            return
        end = time.monotonic() + wait
        while time.monotonic() < end and _alive_in_group(pid):
            time.sleep(0.1)


def _crashed(fault_files, crash_dir):
    """Whether a fatal signal was reported: Python's faulthandler wrote its stacks, or Blender
    its crash report (``<blend name>.crash.txt`` in its temporary directory)."""
    return any(f.is_file() and f.stat().st_size > 0 for f in fault_files) or any(crash_dir.glob("*.crash.txt"))


def run_watched(cmd, env, log_path, fault_files, crash_dir, timeout, grace=GRACE, poll=1.0):
    """Runs ``cmd`` in a process group of its own, its output into ``log_path``. Returns (exit
    code, None) when it ended by itself without a crash report, else (code, why): it crashed,
    or it had to be stopped (past ``timeout`` seconds, or still running ``GRACE`` seconds after
    reporting a crash, ``grace``). The group is killed either way, so that no child (a job's process, Xvfb)
    outlives the test or holds its output open."""
    start = time.monotonic()
    crashed_at = None
    why = None
    with open(log_path, "wb") as fh:
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        try:
            while proc.poll() is None:
                now = time.monotonic()
                if crashed_at is None and _crashed(fault_files, crash_dir):
                    crashed_at = now
                if crashed_at is not None and now - crashed_at > grace:
                    why = f"crashed and was still running {grace} s later: stopped"
                    break
                if now - start > timeout:
                    why = f"ran past {timeout} s: stopped"
                    break
                time.sleep(poll)
        finally:
            _group_kill(proc.pid)
            code = proc.wait()
    if why is None and _crashed(fault_files, crash_dir):
        why = f"crashed (exit code {code})"
    return code, why


def crash_report(faults, crash_dir):
    """Blender's crash report(s) and every Python thread's stack (faulthandler); "" if none."""
    parts = [f"--- {p.name}\n{p.read_text(errors='replace')[-6000:]}" for p in sorted(crash_dir.glob("*.crash.txt"))]
    if faults.is_file() and faults.stat().st_size:
        parts.append(f"--- Python threads (faulthandler)\n{faults.read_text(errors='replace')[-8000:]}")
    return "\n".join(parts)
