"""A float OpenEXR writer without Blender: the textures a job makes are written in the job.

Blender's own writer needs an image datablock, so it runs on the main thread only; an Apply's
finish spent up to 0.2 s there on a texture of 18 x 3 pixels (Blender 3.4's window, under load).
This writes the one form the product needs, in the job's child process or thread, behind the
same atomic write and guard as every other output:

- one part, scanlines in increasing y, no compression, one line per chunk;
- channels A, B, G, R (the format lists them by name), 32-bit float, alpha 1;
- the first row of ``pixels`` is the image's top, as in every image file.

OpenEXR's own reader, Blender and OSL's texture system read it (``tests/test_exr.py``).
"""

from __future__ import annotations

import struct

import numpy as np

from .. import limits
from .atomic import atomic_path
from .safeio import EXR_MAGIC

_FLOAT = 2  # the channel's pixel type: 32-bit IEEE float
_CHANNELS = "ABGR"  # sorted by name, as the format requires


def _attribute(name: str, kind: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def _header(width: int, height: int) -> bytes:
    chlist = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", _FLOAT, 0, 1, 1) for c in _CHANNELS) + b"\0"
    window = struct.pack("<4i", 0, 0, width - 1, height - 1)
    return (
        EXR_MAGIC
        + struct.pack("<I", 2)  # version 2, single-part scanline
        + _attribute("channels", "chlist", chlist)
        + _attribute("compression", "compression", b"\0")
        + _attribute("dataWindow", "box2i", window)
        + _attribute("displayWindow", "box2i", window)
        + _attribute("lineOrder", "lineOrder", b"\0")
        + _attribute("pixelAspectRatio", "float", struct.pack("<f", 1.0))
        + _attribute("screenWindowCenter", "v2f", struct.pack("<2f", 0.0, 0.0))
        + _attribute("screenWindowWidth", "float", struct.pack("<f", 1.0))
        + b"\0"
    )


def exr_bytes(pixels) -> bytes:
    """The file's bytes for an (H, W, 3) or (H, W, 4) array, top row first."""
    a = np.asarray(pixels)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise ValueError(f"an EXR image is (height, width, 3 or 4) pixels, not {a.shape}")
    height, width = a.shape[:2]
    if not (0 < width <= limits.MAX_IMAGE_SIDE and 0 < height <= limits.MAX_IMAGE_SIDE) or (
        width * height > limits.MAX_IMAGE_PIXELS
    ):
        raise ValueError(f"a {width}x{height} image is beyond the product's limit of {limits.MAX_IMAGE_PIXELS} pixels")
    rgba = np.ones((height, width, 4), "<f4")
    rgba[..., : a.shape[2]] = a
    # each line: its y, its size, then each channel's run of the line (A, B, G, R)
    planar = rgba[:, :, [3, 2, 1, 0]].transpose(0, 2, 1).reshape(height, 4 * width)
    line_bytes = 4 * 4 * width
    head = _header(width, height)
    first = len(head) + 8 * height
    offsets = first + np.arange(height, dtype="<u8") * (8 + line_bytes)
    lines = np.empty((height, 8 + line_bytes), np.uint8)
    lines[:, :4] = np.arange(height, dtype="<i4").view(np.uint8).reshape(height, 4)
    lines[:, 4:8] = np.frombuffer(struct.pack("<i", line_bytes), np.uint8)
    lines[:, 8:] = np.ascontiguousarray(planar, "<f4").view(np.uint8)
    return head + offsets.tobytes() + lines.tobytes()


def write_exr(pixels, path, inputs=()) -> str:
    """Write ``pixels`` (H, W, 3 or 4; top row first) to ``path`` atomically; returns the path."""
    data = exr_bytes(pixels)
    with atomic_path(path, ".exr", inputs=inputs) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
    return path
