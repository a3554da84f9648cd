"""Atomic file output: write to a temporary file in the target folder, then rename.

A reader never sees a half-written file: the target is replaced in one step, or not at all.
Every destination first passes ``safeio.guard_output`` (never an input of the run, never a
device, FIFO or folder). On an error or an interrupt the temporary file is removed.

A writer killed outright (SIGKILL, power loss) cannot clean up. So each temporary file or
folder is recorded, when created, in a journal inside the product's cache folder
(``<cache>/pending``: the writer's pid and process start time, the path, its device and
inode). ``sweep_pending`` removes a recorded temporary only when its writer is gone and the
path still holds the very file (same device and inode) that was recorded: nothing the
product cannot prove it created is ever deleted, whatever its name.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import stat
import tempfile

from .safeio import cache_root, guard_output

_ENTRY = re.compile(r"^(\d+)-(\d*)-[0-9a-f]{16}\.json$")
MARKER = ".brdf-moments"  # inside every folder the product creates for itself


def _proc_token(pid: int) -> str:
    """The process's start time where the system tells it (Linux): a reused pid differs."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[19].decode()
    except (OSError, IndexError):
        return ""


def _alive(pid: int, token: str) -> bool:
    if pid == os.getpid():
        return token == _proc_token(pid)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        pass  # exists, not ours (EPERM): compare start times below
    now = _proc_token(pid)
    return not (token and now and now != token)


def pending_dir() -> str:
    return os.path.join(cache_root(), "pending")


def _journal_add(path, kind):
    try:
        st = os.lstat(path)
        folder = pending_dir()
        os.makedirs(folder, exist_ok=True)
        mark_folder(folder)
        entry = os.path.join(folder, f"{os.getpid()}-{_proc_token(os.getpid())}-{secrets.token_hex(8)}.json")
        with open(entry, "w") as fh:
            json.dump({"path": os.path.abspath(path), "dev": st.st_dev, "ino": st.st_ino, "kind": kind}, fh)
        return entry
    except OSError:
        return None  # no journal (an unwritable cache): only a SIGKILL could leave the file now


@contextlib.contextmanager
def tracked(path, kind="file"):
    """Record the temporary ``path`` (just created by us) for the duration of the block."""
    entry = _journal_add(path, kind)
    try:
        yield
    finally:
        if entry:
            with contextlib.suppress(OSError):
                os.unlink(entry)


def sweep_pending(only_pid=None) -> list:
    """Remove temporaries whose writer is gone and that are still the files it recorded."""
    removed = []
    folder = pending_dir()
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        m = _ENTRY.match(name)
        if not m or (only_pid is not None and int(m.group(1)) != only_pid):
            continue
        if _alive(int(m.group(1)), m.group(2)):
            continue
        entry = os.path.join(folder, name)
        try:
            from ..limits import MAX_JOURNAL_ENTRY_BYTES
            from .safeio import read_input

            rec = json.loads(read_input(entry, MAX_JOURNAL_ENTRY_BYTES, "journal entry", register=False))
            path, kind = rec["path"], rec["kind"]
            st = os.lstat(path)
            same = (st.st_dev, st.st_ino) == (rec["dev"], rec["ino"])
            if same and kind == "file" and stat.S_ISREG(st.st_mode):
                os.unlink(path)
                removed.append(path)
            elif same and kind == "dir" and stat.S_ISDIR(st.st_mode):
                shutil.rmtree(path, ignore_errors=True)
                removed.append(path)
        except (OSError, ValueError, KeyError, TypeError):
            pass  # gone already, or an entry cut short by the kill: nothing to prove
        with contextlib.suppress(OSError):
            os.unlink(entry)
    return removed


def mark_folder(folder) -> None:
    """Mark a folder the product has just created as its own (sweeps look for this)."""
    marker = os.path.join(folder, MARKER)
    if not os.path.exists(marker):
        with open(marker, "w") as fh:
            fh.write("created by BRDF Moments; its contents may be removed by it\n")


def is_marked(folder) -> bool:
    return os.path.isfile(os.path.join(folder, MARKER)) and not os.path.islink(os.path.join(folder, MARKER))


def own_folder(folder) -> str:
    """``folder``, created (and marked as the product's) if it did not exist."""
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        parent = os.path.dirname(os.path.abspath(folder))
        os.makedirs(parent, exist_ok=True)
        try:
            os.mkdir(folder)
        except FileExistsError:
            if not os.path.isdir(folder):
                raise
            return folder  # another process made it: it marks it
        mark_folder(folder)
    return folder


@contextlib.contextmanager
def temp_folder(parent, prefix):
    """A tracked temporary folder inside ``parent``, removed when the block fails; on success
    the caller has renamed it into place (or it is removed)."""
    tmp = tempfile.mkdtemp(prefix=prefix, dir=parent)
    with tracked(tmp, "dir"):
        try:
            mark_folder(tmp)
            yield tmp
        finally:
            if os.path.isdir(tmp):
                shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def atomic_path(path, suffix="", inputs=()):
    """Yield a temporary path next to ``path``; on success it becomes ``path`` (mode 0644).

    ``inputs``: files this write must never replace (besides the run's, see safeio)."""
    path = guard_output(path, inputs)
    folder = os.path.dirname(path)
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, folder) from None
    sweep_pending()
    try:
        fd, tmp = tempfile.mkstemp(prefix=".tmp-brdfm-", suffix=suffix, dir=folder)
    except OSError as exc:
        # Name the file the user asked for: the temporary one never existed.
        raise OSError(exc.errno, exc.strerror, path) from None
    os.close(fd)
    with tracked(tmp, "file"):
        try:
            yield tmp
            os.chmod(tmp, 0o644)  # mkstemp makes 0600; an output should read like any other file
            guard_output(path, inputs)  # again: the destination may have changed meanwhile
            try:
                os.replace(tmp, path)
            except OSError as exc:
                raise OSError(exc.errno, exc.strerror, path) from None
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise


def write_json_atomic(data, path, inputs=()):
    """Write JSON atomically; ``allow_nan=False`` means no NaN can get in."""
    with atomic_path(path, ".json", inputs) as tmp, open(tmp, "w") as fh:
        json.dump(data, fh, allow_nan=False)
        fh.write("\n")
