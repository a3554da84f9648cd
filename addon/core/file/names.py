"""Output names that cannot leave the folder they are meant for.

A material or export name comes from the user (a UI field, a file's stem) and may hold
anything: ``../evil``, ``/etc/passwd``, ``C:\\x``, a newline. It is reduced to one plain
file name, and the resolved path is checked to sit inside the chosen folder (which also
catches a symlink planted in the folder that points outside it).
"""

from __future__ import annotations

import os
import unicodedata

from .sources import parse_source

_KEEP = set("-_.+ ()")
# Names Windows reserves in every folder: a file called "con.binary" cannot be created there.
_RESERVED = {"con", "prn", "aux", "nul", *(f"com{i}" for i in range(10)), *(f"lpt{i}" for i in range(10))}
MAX_NAME_BYTES = 200  # below the 255-byte limit of common file systems, with room for a suffix


def file_stem(path) -> str:
    """A material's name from its file: the base name without ``.binary`` (or another extension)."""
    base = os.path.basename(os.fspath(path))
    return base[: -len(".binary")] if base.endswith(".binary") else os.path.splitext(base)[0]


def material_name(source) -> str:
    """A material's name from its source: NAME of ``FILE:NAME`` (a material of a Neural-BRDF
    weights set), else the file's stem."""
    path, name = parse_source(os.fspath(source))
    return name or file_stem(path)


def safe_name(name: str, default: str = "material") -> str:
    """``name`` as a single file name: separators and control characters become ``_``."""
    text = unicodedata.normalize("NFC", str(name))
    cleaned = "".join(c if (c.isalnum() or c in _KEEP) else "_" for c in text)
    while len(cleaned.encode("utf-8")) > MAX_NAME_BYTES:
        cleaned = cleaned[:-1]
    cleaned = cleaned.strip(" .")  # no hidden files, no "..", no trailing dot (Windows drops it)
    if not cleaned or cleaned.split(".")[0].lower() in _RESERVED:
        cleaned = f"{default}_{cleaned}" if cleaned else default
    return cleaned


def safe_export_path(folder, name, suffix: str = ".binary") -> str:
    """Absolute path for ``name`` (+ ``suffix``) inside ``folder``; raises ValueError otherwise."""
    if folder is None or not os.fspath(folder):
        raise ValueError("no output folder chosen")
    base = safe_name(name)
    if suffix and not base.lower().endswith(suffix.lower()):
        base += suffix
    root = os.path.realpath(os.fspath(folder))
    path = os.path.realpath(os.path.join(root, base))
    if os.path.dirname(path) != root:
        raise ValueError(f"{base}: the export would leave the folder {root} (a link inside it points elsewhere)")
    return path


def distinct_name(name: str, default: str = "material") -> str:
    """``safe_name(name)``, with a short hash of ``name`` appended when cleaning changed it.

    Distinct names then never share a file name: ``a b`` and ``a_b`` (or ``a/b`` and ``a_b``)
    clean to the same text, but only the one already clean keeps it as it is."""
    import hashlib

    base = safe_name(name, default)
    if base == name:
        return base
    tag = hashlib.sha1(str(name).encode("utf-8", "surrogatepass")).hexdigest()[:8]
    while len(f"{base}-{tag}".encode("utf-8")) > MAX_NAME_BYTES:
        base = base[:-1]
    return f"{base}-{tag}"


def collisions(names) -> list:
    """Pairs of distinct names whose file names coincide on a case-insensitive file system."""
    seen, out = {}, []
    for n in names:
        k = distinct_name(n).casefold()
        if k in seen and seen[k] != n:
            out.append((seen[k], n))
        seen.setdefault(k, n)
    return out
