"""Nothing is lost (SPEC §7): one guard for every output, one opener for every input.

- ``guard_output(path, inputs)`` refuses a destination that is, or resolves to (a symlink, a
  hard link), an input of the run, or that exists and is not a regular file (a device, a
  FIFO, a folder). ``atomic.atomic_path`` calls it, so no writer can skip it.
- ``open_input(path, max_bytes, kind)`` opens regular files only (a FIFO is refused before
  it is opened, so nothing hangs), checks the size first, and records the file as an input
  of the current run (``run_scope``): a later write over it in the same run is refused.
- ``check_image_header`` reads an EXR or Radiance HDR header and refuses images above
  ``limits.MAX_IMAGE_PIXELS`` before Blender or OpenEXR decodes a single pixel.
- ``load_json`` bounds a JSON's size and nesting and refuses NaN/Infinity literals.

A run is one command (the CLI wraps each command) or one operator's work. Scopes are per
thread: an operator's background work registers and checks in its own thread.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import stat
import struct
import threading

from .. import limits


def display_path(path) -> str:
    """A path as given, but on one line: control characters (a newline in a file name) escaped."""
    text = os.fsdecode(path) if path is not None else "<memory>"
    if not text:
        return "<no file name>"
    return "".join(c if c.isprintable() or c == " " else repr(c)[1:-1] for c in text)


class UnsafePath(ValueError):
    """A path the product refuses to read or write; the message names it and the fault."""

    def __init__(self, path, fault):
        self.path = os.fspath(path) if path is not None else "<memory>"
        self.fault = fault
        super().__init__(f"{display_path(path)}: {fault}")


def describe_mode(mode) -> str:
    for test, what in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISREG, "a regular file"),
    ):
        if test(mode):
            return what
    return "not a regular file"


# --- runs: the inputs of one command or one operator -----------------------------------------

_LOCAL = threading.local()


@contextlib.contextmanager
def run_scope():
    """Collect the inputs opened in this thread until the block ends (nested scopes add up)."""
    stack = getattr(_LOCAL, "stack", None)
    if stack is None:
        stack = _LOCAL.stack = []
    scope = {}
    stack.append(scope)
    try:
        yield scope
    finally:
        stack.remove(scope)


def register_input(path, st=None):
    """Record ``path`` as an input of every open scope of this thread (no scope: nothing)."""
    stack = getattr(_LOCAL, "stack", None)
    if not stack:
        return
    try:
        st = st or os.stat(path)
    except OSError:
        return
    for scope in stack:
        scope[(st.st_dev, st.st_ino)] = os.path.abspath(os.fspath(path))


def run_inputs() -> dict:
    out = {}
    for scope in getattr(_LOCAL, "stack", None) or ():
        out.update(scope)
    return out


def guard_output(path, inputs=()) -> str:
    """The absolute destination, if it may be written; UnsafePath (one line) otherwise."""
    path = os.fspath(path)
    ids = run_inputs()
    for p in inputs:
        if p is None or p == "":
            continue
        try:
            st = os.stat(p)
        except OSError:
            continue
        ids[(st.st_dev, st.st_ino)] = os.path.abspath(os.fspath(p))
    try:
        st = os.stat(path)  # follows symlinks: a link to an input is that input
    except FileNotFoundError:
        return os.path.abspath(path)
    except OSError as exc:
        raise UnsafePath(path, f"cannot check the output ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise UnsafePath(path, f"is {describe_mode(st.st_mode)}, not a regular file; refusing to replace it")
    src = ids.get((st.st_dev, st.st_ino))
    if src is not None:
        same = os.path.abspath(path) == src
        via = "" if same else f" ({display_path(src)}, through a link)"
        raise UnsafePath(
            path, f"is an input of this run{via}; refusing to overwrite the input, choose another output name"
        )
    return os.path.abspath(path)


# --- inputs -----------------------------------------------------------------------------------


def open_input(path, max_bytes, kind="file", register=True):
    """A regular file opened for binary reading, at most ``max_bytes`` long; UnsafePath otherwise.

    The type is checked with ``stat`` before opening (opening a FIFO would block), and again
    on the open descriptor (the name may have been swapped in between)."""
    path = os.fspath(path)
    try:
        st = os.stat(path)
    except OSError as exc:
        raise UnsafePath(path, f"cannot read {kind} ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise UnsafePath(path, f"is {describe_mode(st.st_mode)}, not a regular {kind}")
    if st.st_size > max_bytes:
        raise UnsafePath(path, f"{kind} too large: {st.st_size} bytes, the limit is {max_bytes}")
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise UnsafePath(path, f"cannot read {kind} ({exc.strerror or exc})") from None
    try:
        st2 = os.fstat(fd)
        if not stat.S_ISREG(st2.st_mode) or (st2.st_dev, st2.st_ino) != (st.st_dev, st.st_ino):
            raise UnsafePath(path, f"changed while being opened; not reading this {kind}")
        if st2.st_size > max_bytes:
            raise UnsafePath(path, f"{kind} too large: {st2.st_size} bytes, the limit is {max_bytes}")
        fh = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    if register:
        register_input(path, st2)
    return fh


def read_input(path, max_bytes, kind="file", register=True) -> bytes:
    with open_input(path, max_bytes, kind, register) as fh:
        return fh.read(max_bytes + 1)


def _depth(obj) -> int:
    deepest, todo = 0, [(obj, 1)]
    while todo:
        o, d = todo.pop()
        if isinstance(o, (dict, list)):
            deepest = max(deepest, d)
            todo.extend((v, d + 1) for v in (o.values() if isinstance(o, dict) else o))
    return deepest


def _no_constant(name):
    raise ValueError(f"{name} is not a number JSON allows")


def load_json(path, max_bytes=limits.MAX_PROFILES_JSON_BYTES, kind="JSON file", max_depth=limits.MAX_JSON_DEPTH):
    """A JSON document from a regular file, size and nesting bounded; UnsafePath otherwise."""
    raw = read_input(path, max_bytes, kind)
    try:
        data = json.loads(raw.decode("utf-8"), parse_constant=_no_constant)
    except RecursionError:
        raise UnsafePath(path, f"not valid {kind}: nested deeper than {max_depth} levels") from None
    except UnicodeDecodeError:
        raise UnsafePath(path, f"not valid {kind}: not UTF-8 text") from None
    except ValueError as exc:
        raise UnsafePath(path, f"not valid {kind} ({str(exc).splitlines()[0]})") from None
    if _depth(data) > max_depth:
        raise UnsafePath(path, f"not valid {kind}: nested deeper than {max_depth} levels")
    return data


def load_npz(path, max_bytes, kind="array file", max_members=64, max_unpacked=None):
    """The arrays of an .npz (numbers only, never pickles) from a regular file of at most
    ``max_bytes``; the zip's directory is checked first, so a small file claiming gigabytes
    once unpacked is refused before anything is inflated. UnsafePath for any fault."""
    import io
    import zipfile

    import numpy as np

    max_unpacked = max_unpacked or 4 * max_bytes
    data = read_input(path, max_bytes, kind)
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            infos = zf.infolist()
            if len(infos) > max_members:
                raise UnsafePath(path, f"not a valid {kind}: {len(infos)} members, the limit is {max_members}")
            total = sum(i.file_size for i in infos)
            if total > max_unpacked:
                raise UnsafePath(path, f"not a valid {kind}: it unpacks to {total} bytes, the limit is {max_unpacked}")
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            return {k: np.asarray(z[k]) for k in z.files}
    except UnsafePath:
        raise
    except Exception as exc:  # noqa: BLE001 - zip, zlib and numpy raise many kinds for bad bytes
        why = (str(exc).splitlines() or [""])[0][:120]
        raise UnsafePath(path, f"not a valid {kind} ({type(exc).__name__}: {why})") from None


# --- images -----------------------------------------------------------------------------------

EXR_MAGIC = b"\x76\x2f\x31\x01"
# Scanlines per chunk by EXR compression code (NONE, RLE, ZIPS, ZIP, PIZ, PXR24, B44, B44A, DWAA, DWAB).
_EXR_LINES = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}
_HDR_RES = re.compile(rb"^([-+])([XY]) (\d{1,9}) ([-+])([XY]) (\d{1,9})$")


def _check_size(path, width, height, max_pixels, max_side):
    if width < 1 or height < 1:
        raise UnsafePath(path, f"the image header claims {width}x{height} pixels")
    if width > max_side or height > max_side or width * height > max_pixels:
        raise UnsafePath(
            path,
            f"the image header claims {width}x{height} pixels; the limit is {max_pixels} pixels "
            f"and {max_side} per side",
        )


def _exr_attributes(fh, path):
    """One EXR header's attributes as {name: (type, bytes)}; ends at the empty name."""
    attrs = {}
    for _ in range(1024):
        name = _cstring(fh, path)
        if not name:
            return attrs
        kind = _cstring(fh, path)
        raw = fh.read(4)
        if len(raw) < 4:
            raise UnsafePath(path, "not a valid OpenEXR file: the header is truncated")
        (size,) = struct.unpack("<i", raw)
        if not 0 <= size <= 1 << 20:
            raise UnsafePath(path, f"not a valid OpenEXR file: attribute {name!r} claims {size} bytes")
        value = fh.read(size)
        if len(value) < size:
            raise UnsafePath(path, "not a valid OpenEXR file: the header is truncated")
        attrs[name] = (kind, value)
    raise UnsafePath(path, "not a valid OpenEXR file: more than 1024 header attributes")


def _cstring(fh, path):
    out = bytearray()
    while True:
        c = fh.read(1)
        if not c:
            raise UnsafePath(path, "not a valid OpenEXR file: the header is truncated")
        if c == b"\0":
            return out.decode("latin-1")
        out += c
        if len(out) > 255:
            raise UnsafePath(path, "not a valid OpenEXR file: a header name is longer than 255 bytes")


def _exr_header(fh, path, size, max_pixels, max_side):
    if fh.read(4) != EXR_MAGIC:
        raise UnsafePath(path, "not an OpenEXR file (wrong magic number)")
    raw = fh.read(4)
    if len(raw) < 4:
        raise UnsafePath(path, "not a valid OpenEXR file: the header is truncated")
    (version,) = struct.unpack("<I", raw)
    if version & 0xFF != 2:
        raise UnsafePath(path, f"unsupported OpenEXR version {version & 0xFF}")
    if version & 0x800:
        raise UnsafePath(path, "deep OpenEXR images are not environment maps")
    multipart, tiled = bool(version & 0x1000), bool(version & 0x200)
    parts = []
    while True:
        attrs = _exr_attributes(fh, path)
        if not attrs:
            if multipart and parts:
                break
            raise UnsafePath(path, "not a valid OpenEXR file: empty header")
        parts.append(attrs)
        if not multipart:
            break
        if len(parts) > 64:
            raise UnsafePath(path, "not a valid OpenEXR file: more than 64 parts")
    sizes = []
    for attrs in parts:
        kind, value = attrs.get("dataWindow", ("", b""))
        if kind != "box2i" or len(value) != 16:
            raise UnsafePath(path, "not a valid OpenEXR file: no data window")
        x0, y0, x1, y1 = struct.unpack("<4i", value)
        w, h = x1 - x0 + 1, y1 - y0 + 1
        _check_size(path, w, h, max_pixels, max_side)
        if "channels" not in attrs:
            raise UnsafePath(path, "not a valid OpenEXR file: no channel list")
        sizes.append((w, h, attrs))
    w, h, attrs = sizes[0]
    header_end = fh.tell()
    if not multipart and not tiled:
        comp = attrs.get("compression", ("", b"\0"))[1][:1]
        lines = _EXR_LINES.get(comp[0] if comp else 0)
        if lines is None:
            raise UnsafePath(path, "not a valid OpenEXR file: unknown compression")
        chunks = -(-h // lines)
        table = fh.read(8 * chunks)
        if len(table) < 8 * chunks:
            raise UnsafePath(path, "truncated OpenEXR file: the chunk table is incomplete")
        offsets = struct.unpack(f"<{chunks}Q", table)
        first = header_end + 8 * chunks
        if any(not first <= o < size for o in offsets):
            raise UnsafePath(path, "truncated or damaged OpenEXR file: chunk offsets point outside the file")
    elif size <= header_end:
        raise UnsafePath(path, "truncated OpenEXR file: no pixel data")
    return w, h


def _hdr_header(fh, path, size, max_pixels, max_side):
    first = fh.readline(128).rstrip(b"\r\n")
    if not first.startswith(b"#?"):
        raise UnsafePath(path, "not a Radiance HDR file (no #? signature)")
    for _ in range(1024):
        line = fh.readline(4096)
        if not line:
            raise UnsafePath(path, "not a valid Radiance HDR file: the header is truncated")
        line = line.rstrip(b"\r\n")
        if not line:
            break
        if line.startswith(b"FORMAT=") and line[7:] not in (b"32-bit_rle_rgbe", b"32-bit_rle_xyze"):
            raise UnsafePath(path, f"unsupported Radiance HDR format {line[7:].decode('latin-1')!r}")
    else:
        raise UnsafePath(path, "not a valid Radiance HDR file: the header never ends")
    m = _HDR_RES.match(fh.readline(64).rstrip(b"\r\n"))
    if not m or m.group(2) == m.group(5):
        raise UnsafePath(path, "not a valid Radiance HDR file: no resolution line")
    a, b = int(m.group(3)), int(m.group(6))
    w, h = (b, a) if m.group(2) == b"Y" else (a, b)
    _check_size(path, w, h, max_pixels, max_side)
    if size <= fh.tell():
        raise UnsafePath(path, "truncated Radiance HDR file: no pixel data")
    return w, h


def check_image_header(path, max_pixels=limits.MAX_IMAGE_PIXELS, max_side=limits.MAX_IMAGE_SIDE):
    """(width, height) of an .exr or .hdr file, from its header alone; UnsafePath if the file
    is not one, is truncated, or claims more pixels than the limits. Nothing is decoded."""
    ext = os.path.splitext(os.fspath(path))[1].lower()
    with open_input(path, limits.MAX_IMAGE_BYTES, "image") as fh:
        size = os.fstat(fh.fileno()).st_size
        if ext == ".exr":
            return _exr_header(fh, path, size, max_pixels, max_side)
        if ext == ".hdr":
            return _hdr_header(fh, path, size, max_pixels, max_side)
    raise UnsafePath(path, "not an HDR environment (expected .exr or .hdr)")


def cache_root() -> str:
    """The product's cache folder: $BRDF_MOMENTS_CACHE, else ~/.cache/brdf_moments."""
    env = os.environ.get("BRDF_MOMENTS_CACHE")
    if env:
        return env
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "brdf_moments")
