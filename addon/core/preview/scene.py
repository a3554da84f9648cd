"""The preview's view: unit spheres in a row, seen by an orthographic camera.

World frame as in Blender: z up; the camera looks along +y (Blender's front view), image
x to the right (+x), image up = +z. Every ray is parallel, so the view direction (toward
the viewer) is the constant (0, -1, 0) and a sphere's image depends only on its material,
not on where it sits in the row: a texel of a sphere's bake is a pixel of the render.

Pixel alignment: each sphere is D pixels across and its bounding square starts on a pixel
edge, so texel (a, b) of the bake (b counted from the top) is exactly one render pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

VIEW = np.array([0.0, -1.0, 0.0])  # toward the camera


@dataclass(frozen=True)
class Layout:
    width: int
    height: int
    count: int
    diameter: int  # pixels across one sphere
    lefts: tuple  # left pixel edge of each sphere's bounding square
    top: int  # top pixel edge (the same for all)

    @property
    def pixel(self) -> float:
        """World units per pixel (the spheres have radius 1)."""
        return 2.0 / self.diameter

    @property
    def ortho_scale(self) -> float:
        """Blender's orthographic scale with sensor fit HORIZONTAL."""
        return self.width * self.pixel

    def centre_x(self, k) -> float:
        """World x of sphere k's centre (z = 0, y = 0)."""
        return (self.lefts[k] + 0.5 * self.diameter - 0.5 * self.width) * self.pixel

    def interior_mask(self) -> np.ndarray:
        """(H, W) True where a pixel lies entirely inside a sphere's silhouette."""
        mask = np.zeros((self.height, self.width), bool)
        inner = interior_texels(self.diameter)
        for left in self.lefts:
            mask[self.top : self.top + self.diameter, left : left + self.diameter] |= inner
        return mask

    def compose(self, tiles) -> np.ndarray:
        """Place per-sphere (D, D, C) arrays into an (H, W, C) image (zero elsewhere)."""
        c = np.asarray(tiles[0]).shape[2]
        out = np.zeros((self.height, self.width, c), np.float32)
        for left, tile in zip(self.lefts, tiles):
            out[self.top : self.top + self.diameter, left : left + self.diameter] = tile
        return out


def sphere_layout(width: int, height: int | None = None, count: int = 2, fill: float = 0.9) -> Layout:
    """``count`` spheres side by side, each about ``fill`` of its cell, pixel aligned."""
    from ..limits import check

    width = check("image_side", width, "width")
    height = width if height is None else check("image_side", height, "height")
    count, fill = check("spheres", count), check("fill", fill)
    if width < 4 * count or height < 4 or count < 1:
        raise ValueError(f"image {width}x{height} is too small for {count} sphere(s)")
    cell = width / count
    d = int(fill * min(cell, height))
    if (height - d) % 2:
        d -= 1  # same parity as the height: the row is centred on z = 0
    d = max(d, 2)
    lefts = tuple(int(round(k * cell + 0.5 * (cell - d))) for k in range(count))
    return Layout(width, height, count, d, lefts, (height - d) // 2)


def texel_positions(diameter, a, b, jx, jy):
    """Object-space (x, z) of points inside texels (a = column, b = row from the top)."""
    s = 2.0 / diameter
    return (a + jx) * s - 1.0, 1.0 - (b + jy) * s


def interior_texels(diameter) -> np.ndarray:
    """(D, D) True for texels whose whole square lies inside the unit disk."""
    e = np.arange(diameter + 1) * (2.0 / diameter) - 1.0
    far = np.maximum(e[:-1] ** 2, e[1:] ** 2)  # the corner farthest from the centre
    return (far[None, :] + far[:, None]) < 1.0


def touched_texels(diameter) -> np.ndarray:
    """(D, D) True for texels whose square meets the open unit disk."""
    e = np.arange(diameter + 1) * (2.0 / diameter) - 1.0
    near = np.where((e[:-1] < 0) & (e[1:] > 0), 0.0, np.minimum(e[:-1] ** 2, e[1:] ** 2))
    return (near[None, :] + near[:, None]) < 1.0


def sphere_points(x, z):
    """Front-facing hit points of the unit sphere for camera rays at object (x, z).

    Returns (inside, normal (n, 3), cos_o) with normal = the point itself."""
    r2 = x * x + z * z
    inside = r2 < 1.0
    y = -np.sqrt(np.maximum(1.0 - r2, 0.0))
    n = np.stack([x, y, z], axis=-1)
    return inside, n, -y


def local_frames(n):
    """Tangent t (toward the view) and bitangent b = n x t for normals seen from VIEW.

    In the frame (t, b, n) the view is (sin theta_o, 0, cos theta_o), as SPEC §3 puts it."""
    cos_o = n @ VIEW
    t = VIEW[None, :] - cos_o[:, None] * n
    norm = np.linalg.norm(t, axis=1)
    # At the exact centre the view is the normal and any tangent will do.
    t = np.where(norm[:, None] > 1e-9, t / np.maximum(norm, 1e-300)[:, None], np.array([1.0, 0.0, 0.0]))
    b = np.cross(n, t)
    theta_o = np.arccos(np.clip(cos_o, -1.0, 1.0))
    return t, b, theta_o
