"""Atomic file output: write to a temporary file in the target folder, then rename.

A reader never sees a half-written file: the target is replaced in one step, or not at all.
On an error the temporary file is removed. A writer that is killed outright (SIGKILL, power
loss) cannot clean up, so temporary files are named ``.tmp-<pid>-*``: hidden, recognisable,
and removed by the next atomic write into the same folder once that process is gone.
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile

_TEMP = re.compile(r"^\.tmp-(\d+)-")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # exists but is not ours (EPERM), or cannot tell: keep its file
    return True


def sweep_stale_temps(folder) -> list:
    """Remove temporary files left in ``folder`` by writers that no longer run; returns them."""
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        m = _TEMP.match(name)
        if m and not _alive(int(m.group(1))):
            with contextlib.suppress(OSError):
                os.unlink(os.path.join(folder, name))
                removed.append(name)
    return removed


@contextlib.contextmanager
def atomic_path(path, suffix=""):
    """Yield a temporary path next to ``path``; on success it becomes ``path`` (mode 0644)."""
    path = os.path.abspath(os.fspath(path))
    folder = os.path.dirname(path)
    os.makedirs(folder, exist_ok=True)
    sweep_stale_temps(folder)
    fd, tmp = tempfile.mkstemp(prefix=f".tmp-{os.getpid()}-", suffix=suffix, dir=folder)
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; an output should read like any other file
        try:
            os.replace(tmp, path)
        except OSError as exc:
            # Name the file the user asked for, not our temporary one.
            raise OSError(exc.errno, exc.strerror, path) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
