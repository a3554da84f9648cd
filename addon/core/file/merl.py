"""MERL isotropic BRDF tables: read, validate, write, look up.

Layout (SPEC §2): three little-endian int32 (90, 90, 180), then 3*90*90*180 float64,
channel-major, cell index ``iphi_d + 180*(itheta_d + 90*itheta_h)``. Stored values are
multiplied on read by per-channel scales. Negative stored values mark missing cells.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..geometry import HALF_PI, half_diff_from_directions
from .atomic import atomic_path
from .safeio import UnsafePath, guard_output, open_input

RES_TH, RES_TD, RES_PD = 90, 90, 180
N_CELLS = RES_TH * RES_TD * RES_PD
SHAPE = (RES_TH, RES_TD, RES_PD)
CHANNEL_SCALES = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
HEADER_BYTES = 12
FILE_BYTES = HEADER_BYTES + 3 * N_CELLS * 8
# Far above any measured reflectance (MERL peaks are ~1e4), and low enough that the float32
# sums of the profile integrator and the squares in the fits cannot overflow.
MAX_REFLECTANCE = 1e30


class MerlError(UnsafePath):
    """A MERL file that cannot be used; the message names the file and the fault."""


@dataclass
class MerlTable:
    """A MERL table in reflectance units.

    ``rho`` is (3, N_CELLS) float64 with missing cells set to 0; ``valid`` is the
    (3, N_CELLS) mask of measured cells. Keeping the mask separate means a missing cell can
    never leak into a sum as a negative number.
    """

    rho: np.ndarray
    valid: np.ndarray
    path: str | None = None
    # A display name when the path does not give one (a material decoded from a weights set).
    label: str | None = None

    def __post_init__(self):
        if self.rho.shape != (3, N_CELLS) or self.valid.shape != (3, N_CELLS):
            raise ValueError("MerlTable needs (3, %d) arrays" % N_CELLS)

    @property
    def name(self) -> str:
        if self.label:
            return self.label
        if not self.path:
            return "material"
        from .names import file_stem

        return file_stem(self.path)

    def copy(self) -> "MerlTable":
        return MerlTable(self.rho.copy(), self.valid.copy(), self.path, self.label)


def read_merl(path) -> MerlTable:
    """Read and validate a MERL file. Raises MerlError naming the file and the fault."""
    path = os.fspath(path)
    try:
        fh = open_input(path, 1 << 62, "file")  # the exact size is checked below, after the header
    except UnsafePath as exc:
        raise MerlError(path, exc.fault) from None
    try:
        size = os.fstat(fh.fileno()).st_size
        with fh:
            header = fh.read(HEADER_BYTES)
            if size < HEADER_BYTES:
                raise MerlError(path, f"file too short for a MERL header ({size} bytes, need {FILE_BYTES})")
            dims = tuple(int(v) for v in np.frombuffer(header, dtype="<i4"))
            if dims != SHAPE:
                raise MerlError(path, f"wrong header {dims}, expected {SHAPE} (not a MERL isotropic BRDF?)")
            if size != FILE_BYTES:
                kind = "truncated" if size < FILE_BYTES else "oversized"
                raise MerlError(path, f"{kind}: {size} bytes, a MERL file has exactly {FILE_BYTES}")
            # Read straight into the array: no intermediate 35 MB bytes object.
            stored = np.empty(3 * N_CELLS, dtype="<f8")
            got = fh.readinto(memoryview(stored).cast("B"))
    except OSError as exc:
        raise MerlError(path, f"cannot read file ({exc.strerror or exc})") from None
    if got != 3 * N_CELLS * 8:
        raise MerlError(path, f"truncated while reading ({got + HEADER_BYTES} bytes)")
    return table_from_stored(stored.reshape(3, N_CELLS), path)


def table_from_stored(stored: np.ndarray, path=None) -> MerlTable:
    """Validate raw stored values (3, N_CELLS) and convert them to reflectance."""
    finite = np.isfinite(stored)
    if not finite.all():
        bad = np.argwhere(~finite)[0]
        kind = "NaN" if np.isnan(stored[tuple(bad)]) else "inf"
        count = int((~finite).sum())
        raise MerlError(path, f"{count} non-finite value(s) ({kind} first at channel {bad[0]}, cell {bad[1]})")
    valid = stored >= 0.0
    if not valid.any():
        raise MerlError(path, "no measured cells: every value is negative (missing)")
    rho = stored * CHANNEL_SCALES[:, None]
    rho[~valid] = 0.0
    huge = rho > MAX_REFLECTANCE
    if huge.any():
        bad = np.argwhere(huge)[0]
        raise MerlError(
            path,
            f"{int(huge.sum())} value(s) above {MAX_REFLECTANCE:g}, beyond any reflectance "
            f"(first {rho[tuple(bad)]:.3g} at channel {bad[0]}, cell {bad[1]})",
        )
    return MerlTable(rho, valid, path)


def write_merl(table: MerlTable, path, *, source=None) -> None:
    """Write a MERL file atomically (temp file in the same folder, then rename).

    Refuses to overwrite ``source`` (the file the table was read from), so an edit can
    never clobber its input.
    """
    path = os.path.abspath(os.fspath(path))
    try:
        guard_output(path, (source, table.path))
    except UnsafePath as exc:
        raise MerlError(path, exc.fault) from None
    if not (np.isfinite(table.rho).all()):
        raise MerlError(path, "refusing to write non-finite values")
    if table.rho.max(initial=0.0) > MAX_REFLECTANCE:
        raise MerlError(path, f"refusing to write values above {MAX_REFLECTANCE:g} (read_merl would refuse them)")
    stored = np.where(table.valid, table.rho / CHANNEL_SCALES[:, None], -1.0)
    with atomic_path(path, ".binary", inputs=(source, table.path)) as tmp, open(tmp, "wb") as fh:
        fh.write(np.asarray(SHAPE, dtype="<i4").tobytes())
        fh.write(np.ascontiguousarray(stored, dtype="<f8").tobytes())
        fh.flush()
        os.fsync(fh.fileno())


# --- lookup -----------------------------------------------------------------------------


def cell_indices(theta_h, theta_d, phi_d):
    """Nearest cell (flat index) for Rusinkiewicz angles, as MERL's reference reader."""
    theta_h = np.asarray(theta_h, dtype=float)
    with np.errstate(invalid="ignore"):
        th = np.floor(np.sqrt(np.maximum(theta_h, 0.0) / HALF_PI) * RES_TH)
    ith = np.clip(np.where(theta_h <= 0.0, 0, th), 0, RES_TH - 1).astype(np.int64)
    itd = np.clip(np.floor(np.asarray(theta_d) / HALF_PI * RES_TD), 0, RES_TD - 1).astype(np.int64)
    pd = np.where(phi_d < 0.0, phi_d + np.pi, phi_d)
    ipd = np.clip(np.floor(pd / np.pi * RES_PD), 0, RES_PD - 1).astype(np.int64)
    return ipd + RES_PD * (itd + RES_TD * ith)


def cell_indices_view(theta, phi, sin_e, cos_e):
    """Nearest cell for w_i = m(theta, phi) seen from w_o = (sin e, 0, cos e): a direct form.

    Same cells as ``cell_indices(*half_diff_from_directions(...))`` with a third of the work:
    cos(theta_d) = w_i . h, and phi_d from one atan2 of h's components (no rotations).
    Works in the inputs' precision (float32 halves the cost of a full-table synthesis) and in
    place: at a million cells per call, temporaries cost as much as the trig.
    """
    shape = np.broadcast(theta, phi, sin_e, cos_e).shape
    # At least 1-d and of one shape, so that the in-place steps below work for any caller.
    theta, phi = np.broadcast_arrays(np.atleast_1d(theta), np.atleast_1d(phi))
    dt = np.result_type(theta, phi, np.float32)
    theta, phi = theta.astype(dt, copy=False), phi.astype(dt, copy=False)
    cp = np.cos(phi)
    iy = np.sin(phi)
    ix = np.sin(theta)
    ix *= cp
    iz = np.cos(theta)
    iz *= cp
    hx = ix + np.asarray(sin_e, dt)
    hz = iz + np.asarray(cos_e, dt)
    n = hx * hx
    n += iy * iy
    n += hz * hz
    np.sqrt(n, out=n)
    n[n <= 0.0] = 1.0
    y = hx * iy
    y -= iy * ix
    y *= n
    dot = ix * hx
    dot += iy * iy
    rho2 = hx * hx
    rho2 += iy * iy
    rho2 *= iz
    x = hz * dot
    x -= rho2
    phi_d = np.arctan2(y, x, out=y)
    dot += iz * hz
    dot /= n
    np.clip(dot, -1.0, 1.0, out=dot)
    theta_d = np.arccos(dot, out=dot)
    hz /= n
    np.clip(hz, -1.0, 1.0, out=hz)
    theta_h = np.arccos(hz, out=hz)
    # Indices as cell_indices, in the same precision.
    theta_h *= dt.type(1.0 / HALF_PI)
    np.sqrt(theta_h, out=theta_h)
    theta_h *= RES_TH
    idx = np.minimum(theta_h.astype(np.int64), RES_TH - 1)
    theta_d *= dt.type(RES_TD / HALF_PI)
    itd = np.minimum(theta_d.astype(np.int64), RES_TD - 1)
    phi_d[phi_d < 0.0] += dt.type(np.pi)
    phi_d *= dt.type(RES_PD / np.pi)
    ipd = np.clip(phi_d.astype(np.int64), 0, RES_PD - 1)
    idx *= RES_TD
    idx += itd
    idx *= RES_PD
    idx += ipd
    return idx.reshape(shape)


def theta_h_edges():
    """The edges of the table's theta_h cells (RES_TH + 1, radians): square-root spaced, so the
    cells near the mirror are fine enough for narrow peaks."""
    return (np.arange(RES_TH + 1) / RES_TH) ** 2 * HALF_PI


def cell_centres():
    """Rusinkiewicz angles at which each cell is sampled when tabulating (flat order)."""
    ith, itd, ipd = np.meshgrid(np.arange(RES_TH), np.arange(RES_TD), np.arange(RES_PD), indexing="ij")
    theta_h = ((ith + 0.5) / RES_TH) ** 2 * HALF_PI
    theta_d = (itd + 0.5) / RES_TD * HALF_PI
    phi_d = (ipd + 0.5) / RES_PD * np.pi
    return theta_h.ravel(), theta_d.ravel(), phi_d.ravel()


def _fractional_indices(theta_h, theta_d, phi_d):
    # Continuous index coordinates whose integer points are cell centres.
    fth = np.sqrt(np.clip(theta_h, 0.0, HALF_PI) / HALF_PI) * RES_TH - 0.5
    ftd = np.clip(theta_d, 0.0, HALF_PI) / HALF_PI * RES_TD - 0.5
    pd = np.where(phi_d < 0.0, phi_d + np.pi, phi_d)
    fpd = pd / np.pi * RES_PD - 0.5
    return fth, ftd, fpd


def trilinear_corners(theta_h, theta_d, phi_d):
    """The 8 cells around each point and their trilinear weights: ((8, n) indices, (8, n) weights).

    Along theta_h and theta_d the corners clamp at the table's edges; phi_d is periodic with
    period pi through the reciprocity fold."""
    fth, ftd, fpd = _fractional_indices(
        np.asarray(theta_h, float).ravel(), np.asarray(theta_d, float).ravel(), np.asarray(phi_d, float).ravel()
    )
    axes = []
    for f, n, periodic in ((fth, RES_TH, False), (ftd, RES_TD, False), (fpd, RES_PD, True)):
        i0 = np.floor(f)
        t = f - i0
        i0 = i0.astype(np.int64)
        i1 = i0 + 1
        if periodic:
            i0, i1 = i0 % n, i1 % n
        else:
            i0, i1 = np.clip(i0, 0, n - 1), np.clip(i1, 0, n - 1)
        axes.append(((i0, 1.0 - t), (i1, t)))
    idx = np.empty((8, fth.size), np.int64)
    w = np.empty((8, fth.size))
    k = 0
    for a in axes[0]:
        for b in axes[1]:
            for c in axes[2]:
                idx[k] = c[0] + RES_PD * (b[0] + RES_TD * a[0])
                w[k] = a[1] * b[1] * c[1]
                k += 1
    return idx, w


_HORIZON = {}


def horizon_mask() -> np.ndarray:
    """(N_CELLS,) bool: cells whose centre has both directions above the horizon (the cells a
    tabulated table holds; the Neural-BRDF decodes have the same mask)."""
    if "mask" not in _HORIZON:
        from ..geometry import directions_from_half_diff

        wi, wo = directions_from_half_diff(*cell_centres())
        _HORIZON["mask"] = ~((wi[..., 2] <= 0.0) | (wo[..., 2] <= 0.0)).reshape(N_CELLS)
    return _HORIZON["mask"]


def lookup_angles(table: MerlTable, theta_h, theta_d, phi_d, interp="nearest"):
    """rho for Rusinkiewicz angles: returns (values (3, n), valid (3, n))."""
    if interp == "nearest":
        idx = cell_indices(theta_h, theta_d, phi_d)
        return table.rho[:, idx], table.valid[:, idx]
    if interp != "trilinear":
        raise ValueError(f"unknown interpolation {interp!r}")
    shape = np.shape(theta_h)
    idx, w = trilinear_corners(theta_h, theta_d, phi_d)
    out = np.zeros((3, idx.shape[1]))
    wsum = np.zeros((3, idx.shape[1]))
    for k in range(8):
        ok = table.valid[:, idx[k]]
        wv = np.where(ok, w[k], 0.0)
        out += wv * table.rho[:, idx[k]]
        wsum += wv
    valid = wsum > 1e-12
    # Renormalise over measured neighbours so a missing cell never pulls values down.
    out = np.where(valid, out / np.where(valid, wsum, 1.0), 0.0)
    return out.reshape((3,) + shape), valid.reshape((3,) + shape)


def lookup(table: MerlTable, wi, wo, interp="nearest"):
    """rho(wi, wo) for arrays of unit vectors (..., 3): returns (values (3, ...), valid)."""
    theta_h, theta_d, phi_d = half_diff_from_directions(wi, wo)
    return lookup_angles(table, theta_h, theta_d, phi_d, interp)


def tabulate(brdf, *, path=None) -> MerlTable:
    """Tabulate an analytic BRDF ``brdf(wi, wo) -> (3, n)`` at the cell centres."""
    from ..geometry import directions_from_half_diff

    theta_h, theta_d, phi_d = cell_centres()
    wi, wo = directions_from_half_diff(theta_h, theta_d, phi_d)
    rho = np.asarray(brdf(wi, wo), dtype=float).reshape(3, N_CELLS)
    valid = np.broadcast_to(horizon_mask(), (3, N_CELLS)).copy()
    rho = np.where(valid, np.maximum(rho, 0.0), 0.0)
    return MerlTable(rho, valid, path)
