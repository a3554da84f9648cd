"""Cache files that prove what they hold, and bounded cache folders.

Each cache entry ``X`` is sealed by a small ``X.seal`` written after it: its size and CRC-32.
A read checks the seal first (``verified``), so a truncated or altered entry is a miss and is
rebuilt, never used. The seal also marks the entry as the product's own: ``prune`` removes
only sealed entries (and only while the file is still the size the seal says), least
recently used first, until the folder is within its bounds (``limits``). An entry is marked
used by touching its seal.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
import zlib

from ..limits import MAX_CACHE_ENTRY_BYTES
from .atomic import atomic_path, own_folder
from .safeio import UnsafePath, open_input, read_input

SEAL = ".seal"


def file_crc(path, block=1 << 22) -> tuple:
    """(size, crc32) of a file, read in blocks (about 2.8 GB/s here: 0.14 s for 370 MB)."""
    crc, size = 0, 0
    with open_input(path, MAX_CACHE_ENTRY_BYTES, "cache file", register=False) as fh:
        while block_ := fh.read(block):
            crc = zlib.crc32(block_, crc)
            size += len(block_)
    return size, crc


def write_seal(path) -> None:
    size, crc = file_crc(path)
    with atomic_path(path + SEAL, SEAL) as tmp, open(tmp, "w") as fh:
        json.dump({"entry": os.path.basename(path), "size": size, "crc32": crc}, fh)


def _seal_of(path):
    try:
        raw = read_input(path + SEAL, 4096, "cache seal", register=False)
        seal = json.loads(raw)
        return int(seal["size"]), int(seal["crc32"]), str(seal["entry"])
    except (UnsafePath, OSError, ValueError, KeyError, TypeError):
        return None


def verified(path) -> bool:
    """True if ``path`` is a regular file that its seal vouches for (and marks it used)."""
    seal = _seal_of(path)
    if seal is None or seal[2] != os.path.basename(path):
        return False
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode) or st.st_size != seal[0] or file_crc(path) != seal[:2]:
            return False
    except OSError:
        return False
    with contextlib.suppress(OSError):
        os.utime(path + SEAL)
    return True


def read_verified(path, max_bytes=MAX_CACHE_ENTRY_BYTES):
    """The bytes of a sealed entry, or None (missing, damaged, foreign, too large)."""
    import zlib

    seal = _seal_of(path)
    if seal is None or seal[2] != os.path.basename(path):
        return None
    try:
        data = read_input(path, max_bytes, "cache entry", register=False)
    except (UnsafePath, OSError):
        return None
    if (len(data), zlib.crc32(data)) != seal[:2]:
        return None
    with contextlib.suppress(OSError):
        os.utime(path + SEAL)
    return data


def cache_folder(folder) -> str:
    """The cache folder, created and marked if new."""
    return own_folder(folder)


def prune(folder, max_entries, max_bytes, keep=(), prefix="") -> list:
    """Remove the least recently used sealed entries named ``prefix*`` beyond the bounds;
    returns their names."""
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    entries = []
    for name in names:
        if not name.endswith(SEAL) or not name.startswith(prefix):
            continue
        seal_path = os.path.join(folder, name)
        entry = seal_path[: -len(SEAL)]
        seal = _seal_of(entry)
        if seal is None or seal[2] != os.path.basename(entry):
            continue
        try:
            used = os.stat(seal_path).st_mtime
        except OSError:
            continue
        entries.append((used, entry, seal[0]))
    entries.sort(reverse=True)
    removed, total = [], 0
    keep = {os.path.abspath(k) for k in keep}
    for count, (_, entry, size) in enumerate(entries, 1):
        total += size
        if (count > max_entries or total > max_bytes) and os.path.abspath(entry) not in keep:
            try:
                st = os.lstat(entry)
                if stat.S_ISREG(st.st_mode) and st.st_size == size:
                    os.unlink(entry)
                elif not (stat.S_ISREG(st.st_mode) or stat.S_ISLNK(st.st_mode)):
                    continue  # not a file we could have written: leave it and its seal
            except FileNotFoundError:
                pass
            except OSError:
                continue
            with contextlib.suppress(OSError):
                os.unlink(entry + SEAL)
            removed.append(os.path.basename(entry))
    return removed


def sealed_file(folder, stem, suffix, write, bounds, keep=(), prefix="") -> str:
    """The verified entry ``<stem>-<token><suffix>`` of cache ``folder``, else a new one:
    ``write(path)`` under a fresh token, then sealed. A damaged entry is never written over:
    readers that cache files by path (OIIO's texture system) would keep its old bytes. Then
    the folder is pruned to ``bounds`` (entries, bytes) among entries named ``prefix*``, keeping
    the result and ``keep``."""
    import glob
    import secrets

    folder = cache_folder(folder)
    for path in sorted(glob.glob(os.path.join(glob.escape(folder), f"{glob.escape(stem)}-*{suffix}"))):
        if verified(path):
            break
    else:
        path = os.path.join(folder, f"{stem}-{secrets.token_hex(4)}{suffix}")
        write(path)
        write_seal(path)
    prune(folder, *bounds, keep=(path, *keep), prefix=prefix)
    return path


def check_sealed(path, what="cached file") -> None:
    """Refuse a sealed file whose bytes no longer match its seal (an unsealed one passes:
    its own reader validates it)."""
    if os.path.exists(path + SEAL) and not verified(path):
        raise ValueError(f"{path}: the {what} is damaged (its checksum does not match); make it again")
