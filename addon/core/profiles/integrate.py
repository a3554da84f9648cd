"""Slice integrators: the fast cached operator, analytic functions, Monte Carlo, reference.

All of them produce raw sums ``S[view, channel, monomial]`` about the per-view centre
(theta = c, phi = 0) and leave the statistics to ``moments.profiles_from_sums``.

The fast path: for a fixed list of views, the hybrid rule of ``quadrature.slice_rule`` is
material independent, and a nearest-cell table is constant on each cell. So the rule
collapses, once, into per-view lists of touched cells with the integrals of the 15
monomials over each cell's part of the slice. Analysing a material is then one gather and
one small matrix product per view.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
from dataclasses import dataclass

import numpy as np

from ..file.cachefs import file_crc
from ..file.merl import N_CELLS, cell_indices, horizon_mask, trilinear_corners
from ..geometry import HALF_PI, half_diff_from_directions, view_centred
from .moments import exponents, monomials, n_monomials
from .quadrature import RuleParams, SliceRule, graded_tensor_rule, slice_rule_parts

OPERATOR_VERSION = (
    9  # 8: lines split at cell edges (cell-exact along rays and strip lines); 9: the 0 deg view as its limit
)

# The normal view reads the table as its limit from above. At theta_o = 0 every direction pair
# has phi_d = 0 or pi exactly: the whole slice lies on the edge between the first and the last
# phi_d cells, and rounding picked a side (70/30 by area in the fast rule, 59/41 in the
# reference, on a decoded spectralon: sigma^2 off by 12 %). For theta_o > 0 the two halves of
# the hemisphere fall on either side of that edge, so the limit is well defined; the tables are
# read at this tiny elevation instead (the moments move by O(1e-6)).
NORMAL_VIEW = 1e-6  # rad
MAX_ORDER = 4


def default_cache_dir() -> str:
    from ..file.safeio import cache_root

    return cache_root()


def default_views(count: int = 90, max_deg: float = 89.0) -> np.ndarray:
    """theta_o samples in radians: 0 .. max_deg inclusive, ``count`` of them."""
    from ..limits import check

    count = check("elevations", count, "count (elevations)")
    max_deg = check("max_elevation", max_deg, "max_deg (max elevation)")
    if count == 1:
        return np.array([0.0])
    return np.radians(np.linspace(0.0, max_deg, count))


@dataclass
class SliceOperator:
    """Per-view cell lists and monomial weights (about x = theta + theta_o, phi).

    ``weights`` are about the mirror direction, which is where measured lobes sit: one gather
    and one float32 product give all the sums. A lobe far from the mirror and narrow would
    lose its higher central moments in the shift from the mirror to its mean, so each cell
    also carries its centroid and its moments about that centroid (``local``): sums about
    any centre are rebuilt from those without cancellation (``centred_view_sums``).
    """

    theta_o: np.ndarray
    offsets: np.ndarray
    cells: np.ndarray
    weights: np.ndarray  # (total, 15) float32, contiguous (a strided slice would be copied per view)
    albedo: np.ndarray  # (total,) float32: integral of cos(theta_i) dw_i over each cell's part
    centroid: np.ndarray  # (total, 2) float32: each cell part's mean (x, phi)
    local: np.ndarray  # (total, 14) float32: moments about the centroid, exponents(4)[1:]

    def view(self, k):
        a, b = self.offsets[k], self.offsets[k + 1]
        return self.cells[a:b], self.weights[a:b]

    def albedo_view(self, k):
        a, b = self.offsets[k], self.offsets[k + 1]
        return self.cells[a:b], self.albedo[a:b]

    @property
    def centres(self):
        return -self.theta_o


def _build_view(theta_o, params):
    # The rule piece by piece, keeping only what the sums need (x, phi, weight, cell).
    theta_o = max(float(theta_o), NORMAL_VIEW)  # the normal view as its limit (see NORMAL_VIEW)
    xs, ps, ws, cs = [], [], [], []
    for part in slice_rule_parts(theta_o, params):
        if params.interp == "trilinear":
            # Each node spreads over its 8 corner cells with its trilinear weights, renormalised
            # over the cells above the horizon (as lookup_angles renormalises over measured
            # ones): the sums stay linear in the cells' values, so this is one more operator.
            idx, frac = trilinear_corners(part.theta_h, part.theta_d, part.phi_d)
            frac *= horizon_mask()[idx]
            den = frac.sum(axis=0)
            keep = den > 1e-12
            frac = frac[:, keep] / den[keep]
            idx = idx[:, keep]
            used = frac > 0.0
            cs.append(idx[used])
            xs.append(np.broadcast_to(part.theta[keep] + theta_o, frac.shape)[used])
            ps.append(np.broadcast_to(part.phi[keep], frac.shape)[used])
            ws.append((frac * part.weight[keep])[used])
        else:
            cs.append(cell_indices(part.theta_h, part.theta_d, part.phi_d))
            xs.append(part.theta + theta_o)
            ps.append(part.phi)
            ws.append(part.weight)
        del part
    rule = SliceRule(np.concatenate(xs), np.concatenate(ps), np.concatenate(ws), None, None, None)
    cells = np.concatenate(cs)
    del xs, ps, ws, cs
    uniq, inv = np.unique(cells, return_inverse=True)
    del cells
    x = rule.theta
    rule.theta = None
    agg = np.empty((len(uniq), n_monomials(MAX_ORDER)), dtype=np.float32)
    # One monomial at a time: materialising all 15 for ~600k nodes would dominate the peak.
    xp = rule.weight.copy()
    for n in range(MAX_ORDER + 1):
        wp = xp.copy()
        for m in range(MAX_ORDER + 1 - n):
            agg[:, exponents(MAX_ORDER).index((n, m))] = np.bincount(inv, weights=wp, minlength=len(uniq))
            wp *= rule.phi
        xp *= x
    # cos(theta_i) dw = cos(theta) cos(phi) * cos(phi) dtheta dphi: albedo from the same cells.
    alb = np.bincount(inv, weights=rule.weight * np.cos(x - theta_o) * np.cos(rule.phi) ** 2, minlength=len(uniq))
    # Centroid of each cell's part, rounded to what is stored, and moments about it: exact
    # for the stored centre, so nothing is lost when sums are later moved to another centre.
    mass = np.bincount(inv, weights=rule.weight, minlength=len(uniq))
    mass = np.where(mass > 0, mass, 1.0)
    cen = np.stack(
        [
            np.bincount(inv, weights=rule.weight * x, minlength=len(uniq)) / mass,
            np.bincount(inv, weights=rule.weight * rule.phi, minlength=len(uniq)) / mass,
        ],
        axis=1,
    )
    cen = cen.astype(np.float32)
    lx = x - cen[inv, 0].astype(float)
    lp = rule.phi - cen[inv, 1].astype(float)
    local = np.empty((len(uniq), n_monomials(MAX_ORDER) - 1), dtype=np.float32)
    xp = rule.weight.copy()
    for n in range(MAX_ORDER + 1):
        wp = xp.copy()
        for m in range(MAX_ORDER + 1 - n):
            if n or m:
                local[:, exponents(MAX_ORDER).index((n, m)) - 1] = np.bincount(inv, weights=wp, minlength=len(uniq))
            wp *= lp
        xp *= lx
    return uniq.astype(np.int32), agg, alb.astype(np.float32), cen, local


_PARTS = ("cells", "weights", "albedo", "centroid", "local")


def _build_chunks(theta_o, params, progress):
    parts = {name: [] for name in _PARTS}
    for k, t in enumerate(theta_o):
        for name, arr in zip(_PARTS, _build_view(float(t), params)):
            parts[name].append(arr)
        if progress:
            progress(k + 1, len(theta_o))
    offsets = np.concatenate(([0], np.cumsum([len(c) for c in parts["cells"]]))).astype(np.int64)
    return parts, offsets


def _operator_key(theta_o, params):
    h = hashlib.sha256()
    h.update(repr((OPERATOR_VERSION, params.key())).encode())
    h.update(np.ascontiguousarray(theta_o, dtype="<f8").tobytes())
    return h.hexdigest()[:20]


# "s": sealed folders (marker and checksums), so older unsealed ones are never taken for ours.
_OPERATOR_PREFIX = f"operator-v{OPERATOR_VERSION}s-"
_SEAL = "seal.json"

_MEMO: dict = {}
_SMALL: dict = {}  # single-view operators (the 45 deg diffuse slice)


def get_operator(theta_o, params: RuleParams = RuleParams(), cache_dir=None, progress=None, memo=True) -> SliceOperator:
    """The operator for these views, from memory, the disk cache (verified against its
    checksums once per process), or built (and cached)."""
    theta_o = np.asarray(theta_o, dtype=float)
    key = _operator_key(theta_o, params)
    if key in _MEMO:
        return _MEMO[key]
    if not memo and key in _SMALL:
        return _SMALL[key]
    folder = os.path.join(cache_dir or default_cache_dir(), f"{_OPERATOR_PREFIX}{key}")
    op = None
    if os.path.isdir(folder):
        op = _load_operator(folder, theta_o)
        if op is None and not _discard(folder):
            folder = None  # damaged and not provably ours: leave it, build in memory
    if op is None and folder is not None:
        # Stream each view's part into the cache as it is built and map the result back:
        # holding all views in memory (let alone concatenating them) would dominate the peak.
        op = _build_into_cache(theta_o, params, folder, progress)
    if op is None:  # the cache cannot be written: build in memory
        parts, offsets = _build_chunks(theta_o, params, progress)
        op = SliceOperator(theta_o, offsets, **{k: np.concatenate(v) for k, v in parts.items()})
        del parts
    if not memo:
        _SMALL[key] = op
    else:
        _MEMO.clear()  # keep one operator in memory: they are large
        _MEMO[key] = op
    return op


_PART_LAYOUT = {
    "cells": (np.int32, ()),
    "weights": (np.float32, (n_monomials(MAX_ORDER),)),
    "albedo": (np.float32, ()),
    "centroid": (np.float32, (2,)),
    "local": (np.float32, (n_monomials(MAX_ORDER) - 1,)),
}
_FILES = ("theta_o.npy", "offsets.npy") + tuple(f"{k}.npy" for k in _PARTS)


def _load_operator(folder, theta_o=None):
    """The operator in ``folder`` if its seal holds (every file's size and CRC-32, the views);
    None for anything damaged, missing or foreign: a damaged cache is rebuilt, never trusted."""
    import json
    import stat

    from ..file.atomic import is_marked

    try:
        if not is_marked(folder):
            return None
        from ..file.safeio import read_input

        seal = json.loads(read_input(os.path.join(folder, _SEAL), 1 << 16, "cache seal", register=False))
        for name in _FILES:
            path = os.path.join(folder, name)
            if not stat.S_ISREG(os.stat(path).st_mode) or list(file_crc(path)) != list(seal["files"][name]):
                return None
        # np.load's default allow_pickle=False: a cache file can hold numbers, never objects.
        views = np.load(os.path.join(folder, "theta_o.npy"))
        offsets = np.load(os.path.join(folder, "offsets.npy"))
        parts = {k: np.load(os.path.join(folder, f"{k}.npy"), mmap_mode="r") for k in _PARTS}
    except (OSError, ValueError, EOFError, KeyError, TypeError):  # UnsafePath is a ValueError
        return None
    if theta_o is not None and (views.shape != np.shape(theta_o) or not np.array_equal(views, theta_o)):
        return None
    n = int(offsets[-1]) if offsets.ndim == 1 and len(offsets) == len(views) + 1 else -1
    if n < 0 or offsets[0] != 0 or (np.diff(offsets) < 0).any():
        return None
    for k, (dtype, tail) in _PART_LAYOUT.items():
        if parts[k].shape != (n,) + tail or parts[k].dtype != dtype:
            return None
    cells = parts["cells"]
    if n and (int(cells.min()) < 0 or int(cells.max()) >= N_CELLS):
        return None
    with contextlib.suppress(OSError):
        os.utime(os.path.join(folder, _SEAL))  # recently used: evicted last
    return SliceOperator(views, offsets, **parts)


def _discard(folder) -> bool:
    """Remove an operator folder, only if it carries the product's marker; True if removed."""
    from ..file.atomic import is_marked

    if not is_marked(folder):
        return False
    trash = f"{folder}.discard-{os.getpid()}"
    try:
        os.replace(folder, trash)
    except OSError:
        return False
    shutil.rmtree(trash, ignore_errors=True)
    return True


def sweep_operator_cache(parent, keep=()) -> list:
    """Remove the operator folders no current build will read (other code versions), and the
    least recently used current ones beyond ``limits.OPERATOR_CACHE_MAX_*``. Only folders
    carrying the product's marker are touched. Returns the names removed."""
    from ..file.atomic import is_marked
    from ..limits import OPERATOR_CACHE_MAX_BYTES, OPERATOR_CACHE_MAX_ENTRIES

    removed, current = [], []
    try:
        names = os.listdir(parent)
    except OSError:
        return removed
    for name in names:
        path = os.path.join(parent, name)
        if not name.startswith("operator-") or os.path.islink(path) or not os.path.isdir(path) or not is_marked(path):
            continue
        if not name.startswith(_OPERATOR_PREFIX) and name not in keep:
            if _discard(path):
                removed.append(name)
            continue
        try:
            used = os.stat(os.path.join(path, _SEAL)).st_mtime
            size = sum(os.path.getsize(os.path.join(path, f)) for f in _FILES)
        except OSError:
            used, size = 0.0, 0
        current.append((float("inf") if name in keep else used, name, size))
    current.sort(reverse=True)
    total, count = 0, 0
    for _used, name, size in current:
        total += size
        count += 1
        if (count > OPERATOR_CACHE_MAX_ENTRIES or total > OPERATOR_CACHE_MAX_BYTES) and name not in keep:
            if _discard(os.path.join(parent, name)):
                removed.append(name)
    return removed


def _build_into_cache(theta_o, params, folder, progress):
    """Build view by view into a temporary folder next to ``folder``, then rename it into
    place; returns the memory-mapped operator, or None if the cache cannot be written. An
    interrupt or an error removes the temporary folder."""
    import json

    from ..file.atomic import own_folder, sweep_pending, temp_folder

    parent = os.path.dirname(folder)
    try:
        own_folder(parent)
        sweep_pending()
        build = temp_folder(parent, f".tmp-brdfm-op-{os.getpid()}-")
        tmp = build.__enter__()
    except OSError:
        return None  # an unwritable cache only costs time
    try:
        raw = {k: open(os.path.join(tmp, f"{k}.raw"), "wb") for k in _PARTS}
        counts = []
        try:
            for k, t in enumerate(theta_o):
                arrays = _build_view(float(t), params)
                for name, arr in zip(_PARTS, arrays):
                    raw[name].write(np.ascontiguousarray(arr, dtype=_PART_LAYOUT[name][0]).tobytes())
                counts.append(len(arrays[0]))
                del arrays
                if progress:
                    progress(k + 1, len(theta_o))
        finally:
            for fh in raw.values():
                fh.close()
        offsets = np.concatenate(([0], np.cumsum(counts))).astype(np.int64)
        np.save(os.path.join(tmp, "theta_o.npy"), theta_o)
        np.save(os.path.join(tmp, "offsets.npy"), offsets)
        for name, (dtype, tail) in _PART_LAYOUT.items():
            src = os.path.join(tmp, f"{name}.raw")
            with open(os.path.join(tmp, f"{name}.npy"), "wb") as out, open(src, "rb") as fh:
                np.lib.format.write_array_header_2_0(
                    out, {"descr": np.dtype(dtype).str, "fortran_order": False, "shape": (int(offsets[-1]),) + tail}
                )
                shutil.copyfileobj(fh, out, 1 << 24)
            os.unlink(src)
        with open(os.path.join(tmp, _SEAL), "w") as fh:
            json.dump({"version": OPERATOR_VERSION, "files": {f: file_crc(os.path.join(tmp, f)) for f in _FILES}}, fh)
        if not os.path.isdir(folder):  # else another process won the race; keep theirs
            os.replace(tmp, folder)
    except OSError:
        build.__exit__(None, None, None)
        return None
    except BaseException:
        build.__exit__(None, None, None)  # Ctrl-C, Esc: no half-built folder is left
        raise
    build.__exit__(None, None, None)
    sweep_operator_cache(parent, keep=(os.path.basename(folder),))
    return _load_operator(folder, theta_o)


def table_sums(op: SliceOperator, values: np.ndarray, max_order: int = MAX_ORDER) -> np.ndarray:
    """Raw sums (views, channels, monomials) for per-cell values (N_CELLS, channels)."""
    from ..threads import parallel_map

    nm = n_monomials(max_order)
    n = len(op.theta_o)
    out = np.empty((n, values.shape[1], nm))

    def run(views):
        for k in views:
            cells, w = op.view(k)
            w = w[:, :nm]
            if values.dtype != w.dtype:
                w = np.asarray(w, dtype=values.dtype)
            out[k] = values[cells].T @ w

    # Each view's sums alone, so the views split in two runs of about equal pairs (the gathers
    # and products let go of the GIL) give the same numbers as one run.
    offsets = np.asarray(op.offsets)
    half = int(np.clip(np.searchsorted(offsets, offsets[-1] / 2), 1, n)) if n > 1 else n
    parallel_map(run, [range(0, half), range(half, n)])
    return out


def centred_view_sums(
    op: SliceOperator, k: int, values: np.ndarray, centre_x, centre_phi, max_order: int = MAX_ORDER
) -> np.ndarray:
    """Sums (channels, monomials) of view ``k``, channel c about (centre_x[c], centre_phi[c]).

    ``values`` is (N_CELLS, channels); the sums are in float64. Each cell's moments about its
    own centroid are moved to the channel's centre: near the centre (where a lobe's mass is)
    every term is small, and far cells add only positive even powers, so nothing large
    cancels. This is the two-pass (centred) algorithm, with the cells' parts as first pass.
    """
    from math import comb

    ex_ = exponents(max_order)
    index = {e: i for i, e in enumerate(ex_)}
    a, b = op.offsets[k], op.offsets[k + 1]
    cells = op.cells[a:b]
    v = np.asarray(values[cells], dtype=float).T  # (C, n)
    lit = np.flatnonzero(v.any(axis=0))  # a narrow lobe lights few of the view's cells
    v = v[:, lit]
    local = np.empty((len(lit), len(ex_)))  # about each centroid
    local[:, 0] = op.weights[a:b, 0][lit]
    local[:, 1:] = op.local[a:b, : len(ex_) - 1][lit]  # exponents(max_order) prefixes exponents(4)
    cen = np.asarray(op.centroid[a:b][lit], dtype=float)
    ex = cen[None, :, 0] - np.atleast_1d(np.asarray(centre_x, float))[:, None]  # (C, n)
    ep = cen[None, :, 1] - np.atleast_1d(np.asarray(centre_phi, float))[:, None]
    px, pp = [np.ones_like(ex)], [np.ones_like(ep)]
    for _ in range(max_order):
        px.append(px[-1] * ex)
        pp.append(pp[-1] * ep)
    out = np.zeros((v.shape[0], len(ex_)))
    # Every shift's weighted cells once (C, shifts, n): the shifts an order o needs, those of
    # order up to max_order - o, are the first ones (exponents are ordered by total order).
    vx = [v * p for p in px]
    q_all = np.stack([vx[s] * pp[t] for s, t in ex_], axis=1)
    for o in range(max_order + 1):
        loc_cols = [index[(o - j, j)] for j in range(o + 1)]
        shifts = exponents(max_order - o)
        q = q_all[:, : len(shifts)]
        prod = q @ local[:, loc_cols]  # (C, shifts, o + 1)
        for si, (s, t) in enumerate(shifts):
            for li, j in enumerate(range(o + 1)):
                i = o - j
                out[:, index[(s + i, t + j)]] += comb(s + i, i) * comb(t + j, j) * prod[:, si, li]
    return out


# --- analytic slices ---------------------------------------------------------------------


def find_peak(f, theta_o, n0=129, iters=12, hint=None):
    """Locate the maximum of a slice function on [-pi/2, pi/2]^2 by repeated zooming.

    The mirror direction (and ``hint``) are always candidates: a lobe far narrower than the
    first grid's spacing would otherwise be stepped over.
    """
    candidates = [(-theta_o, 0.0)] + ([tuple(hint)] if hint is not None else [])
    ct, cp, half = 0.0, 0.0, HALF_PI
    n = n0
    best = -np.inf
    for _ in range(iters):
        t = np.clip(np.linspace(ct - half, ct + half, n), -HALF_PI, HALF_PI)
        p = np.clip(np.linspace(cp - half, cp + half, n), -HALF_PI, HALF_PI)
        T, P = np.meshgrid(t, p, indexing="ij")
        pts_t = np.concatenate((T.ravel(), [c[0] for c in candidates]))
        pts_p = np.concatenate((P.ravel(), [c[1] for c in candidates]))
        v = np.asarray(f(pts_t, pts_p, theta_o), dtype=float).reshape(-1, pts_t.size).sum(axis=0)
        i = int(np.argmax(v))
        if v[i] >= best:
            best = v[i]
            ct, cp = float(pts_t[i]), float(pts_p[i])
        candidates = [(ct, cp)]
        half *= 8.0 / (n - 1)
        n = 33
        if half < 1e-9:
            break
    return ct, cp


def function_sums(f, theta_o, max_order=MAX_ORDER, r0=1e-6, n_gauss=8, ratio=1.35, chunk=400, centre=None):
    """Raw sums of an analytic slice ``f(theta, phi, theta_o) -> (C, n) or (n,)``.

    Returns (sums (views, C, monomials), centre_theta (views,), centre_phi (views,)).
    A graded tensor rule around each view's located peak resolves lobes down to 1e-5 rad.
    ``centre(theta_o) -> (theta, phi)`` may hint where the peak is.
    """
    theta_o = np.atleast_1d(np.asarray(theta_o, dtype=float))
    nm = n_monomials(max_order)
    res, ct_all, cp_all = [], [], []
    for to in theta_o:
        ct, cp = find_peak(f, to, hint=None if centre is None else centre(to))
        t, wt, p, wp = graded_tensor_rule(ct, cp, r0, n_gauss, ratio)
        acc = None
        for i in range(0, len(t), chunk):
            T, P = np.meshgrid(t[i : i + chunk], p, indexing="ij")
            W = np.outer(wt[i : i + chunk], wp).ravel()
            v = np.asarray(f(T.ravel(), P.ravel(), to), dtype=float)
            v = v.reshape(-1, T.size)
            part = (v * W) @ monomials(T.ravel() - ct, P.ravel() - cp, max_order)
            acc = part if acc is None else acc + part
        res.append(acc)
        ct_all.append(ct)
        cp_all.append(cp)
    return np.asarray(res).reshape(len(theta_o), -1, nm), np.asarray(ct_all), np.asarray(cp_all)


# --- Monte Carlo (paper Eq. 6) -----------------------------------------------------------


def monte_carlo_sums(evaluate, theta_o, n_samples, seed=0, max_order=MAX_ORDER, chunk=1 << 18):
    """Paper Eq. 6: uniform samples on [-pi/2, pi/2]^2, mean of pi^2 rho x^n phi^m.

    ``evaluate(theta, phi, theta_o) -> (C, n)``. Sums are about (-theta_o, 0) as elsewhere.
    """
    rng = np.random.default_rng(seed)
    theta_o = np.atleast_1d(np.asarray(theta_o, dtype=float))
    out = None
    for k, to in enumerate(theta_o):
        left = n_samples
        acc = 0.0
        while left > 0:
            n = min(chunk, left)
            left -= n
            t = rng.uniform(-HALF_PI, HALF_PI, n)
            p = rng.uniform(-HALF_PI, HALF_PI, n)
            v = np.asarray(evaluate(t, p, to), dtype=float).reshape(-1, n)
            acc = acc + v @ monomials(t + to, p, max_order)
        acc = acc * (np.pi**2 / n_samples)
        if out is None:
            out = np.empty((len(theta_o),) + acc.shape)
        out[k] = acc
    return out


def table_slice_evaluator(values):
    """Slice function for per-cell values (N_CELLS, C), nearest lookup as MERL's reader."""

    def evaluate(theta, phi, theta_o):
        wi = view_centred(theta, phi)
        wo = np.broadcast_to(view_centred(theta_o, 0.0), wi.shape)
        return values[cell_indices(*half_diff_from_directions(wi, wo))].T

    return evaluate


def grid_sums(evaluate, theta_o, n, max_order=MAX_ORDER):
    """Uniform n x n midpoint grid over [-pi/2, pi/2]^2: the naive baseline."""
    theta_o = np.atleast_1d(np.asarray(theta_o, dtype=float))
    x = (np.arange(n) + 0.5) * (np.pi / n) - HALF_PI
    T, P = np.meshgrid(x, x, indexing="ij")
    out = []
    for to in theta_o:
        v = np.asarray(evaluate(T.ravel(), P.ravel(), to), dtype=float).reshape(-1, T.size)
        out.append((v * (np.pi / n) ** 2) @ monomials(T.ravel() + to, P.ravel(), max_order))
    return np.asarray(out)


# --- converged reference for tables ------------------------------------------------------


def _rect_moments(t0, t1, p0, p1, max_order):
    """Exact integrals of x^n phi^m over rectangles (x = theta - centre already applied)."""
    kx = np.arange(1, max_order + 2)
    ix = (t1[:, None] ** kx - t0[:, None] ** kx) / kx
    ip = (p1[:, None] ** kx - p0[:, None] ** kx) / kx
    return np.stack([ix[:, n] * ip[:, m] for n, m in exponents(max_order)], axis=-1)


def reference_sums(values, theta_o, max_order=MAX_ORDER, tol=1e-7, max_level=8, max_refine=400_000, per_ring=3):
    """Converged integral of a nearest-cell table over one view, by adaptive subdivision.

    Independent of the fast rule: it works in (theta, phi), integrates panels that fall
    inside one cell exactly (closed-form rectangle moments), and splits panels that straddle
    cell boundaries, largest estimated error first. Slow; meant for tests and benchmarks.
    """
    values = np.asarray(values, dtype=float)
    evaluate_cells = _cell_lookup(theta_o)
    e_t = _graded(-theta_o, per_ring)
    e_p = _graded(0.0, per_ring)
    T0, P0 = np.meshgrid(e_t[:-1], e_p[:-1], indexing="ij")
    T1, P1 = np.meshgrid(e_t[1:], e_p[1:], indexing="ij")
    panels = np.stack([T0.ravel(), T1.ravel(), P0.ravel(), P1.ravel()], axis=1)
    probe = np.linspace(0.0, 1.0, 4)  # includes the edges: a boundary cannot hide there
    frac = np.array([1.0, 3.0, 5.0]) / 6.0  # sub-rectangle centres for mixed panels
    total = np.zeros((values.shape[1], n_monomials(max_order)))
    scale = None

    def sample(t0, t1, p0, p1, f):
        T = np.repeat(t0[:, None] + (t1 - t0)[:, None] * f, len(f), axis=1)  # t index major
        P = np.tile(p0[:, None] + (p1 - p0)[:, None] * f, (1, len(f)))
        return evaluate_cells(T.ravel(), P.ravel()).reshape(T.shape)

    for level in range(max_level + 1):
        if len(panels) == 0:
            break
        t0, t1, p0, p1 = panels.T
        ids = sample(t0, t1, p0, p1, probe)
        v = values[ids]  # (P, 16, C)
        s = v.sum(axis=2)
        uniform = (ids == ids[:, :1]).all(axis=1)
        area = (t1 - t0) * (p1 - p0)
        err = np.where(uniform, 0.0, (s.max(axis=1) - s.min(axis=1)) * area)
        if scale is None:
            scale = max(float((s.mean(axis=1) * area).sum()), 1e-300)
        refine = err > tol * scale
        if level == max_level:
            refine[:] = False
        elif refine.sum() > max_refine:
            cut = np.partition(err, len(err) - max_refine)[len(err) - max_refine]
            refine = err >= cut
        done = ~refine
        # Uniform panels: one value times exact moments.
        u = done & uniform
        if u.any():
            total += v[u, 0, :].T @ _rect_moments(t0[u] + theta_o, t1[u] + theta_o, p0[u], p1[u], max_order)
        # Mixed panels that are small enough: 3x3 sub-rectangles, each valued at its centre.
        m = done & ~uniform
        if m.any():
            vm = values[sample(t0[m], t1[m], p0[m], p1[m], frac)]
            dt = (t1[m] - t0[m]) / 3.0
            dp = (p1[m] - p0[m]) / 3.0
            for a in range(3):
                for b in range(3):
                    st0 = t0[m] + a * dt
                    sp0 = p0[m] + b * dp
                    mom = _rect_moments(st0 + theta_o, st0 + dt + theta_o, sp0, sp0 + dp, max_order)
                    total += vm[:, 3 * a + b, :].T @ mom
        r = panels[refine]
        tm = 0.5 * (r[:, 0] + r[:, 1])
        pm = 0.5 * (r[:, 2] + r[:, 3])
        panels = np.concatenate(
            [
                np.stack([r[:, 0], tm, r[:, 2], pm], 1),
                np.stack([tm, r[:, 1], r[:, 2], pm], 1),
                np.stack([r[:, 0], tm, pm, r[:, 3]], 1),
                np.stack([tm, r[:, 1], pm, r[:, 3]], 1),
            ]
        )
    return total


def _graded(centre, per_ring):
    # Square-root spacing about the mirror, like the table's theta_h rings (ring k of the
    # table sits at about pi (k/90)^2 from the mirror), so no initial panel is wider than
    # a third of the ring it lies on and the 3x3 probe cannot step over a whole ring.
    k = np.arange(90 * per_ring + 1)
    d = np.pi * (k / (90 * per_ring)) ** 2
    e = np.concatenate((centre - d, centre + d, [-HALF_PI, HALF_PI]))
    return np.unique(np.clip(e, -HALF_PI, HALF_PI))


def _cell_lookup(theta_o):
    wo = view_centred(max(float(theta_o), NORMAL_VIEW), 0.0)  # the normal view as its limit

    def cells(t, p):
        wi = view_centred(t, p)
        return cell_indices(*half_diff_from_directions(wi, np.broadcast_to(wo, wi.shape)))

    return cells


def strided_views(n: int, stride: int) -> list:
    """The indices of every ``stride``-th of ``n`` views and the last one (the grazing end is
    where albedos and bounds are largest, so a subset always keeps it)."""
    return sorted(set(range(0, n, stride)) | {n - 1})


def directional_albedo(table, views=None, stride: int = 1) -> np.ndarray:
    """(views, 3): integral of rho cos(theta_i) over the hemisphere for each view (default:
    the profiles' default views); with ``stride``, every stride-th view and the last one only.
    An edit measures it at its analysed views, with the same operator as its profiles: a second
    set of views cost a second operator (28 s cold)."""
    from ..limits import check

    stride = check("stride", stride, "stride")
    views = default_views() if views is None else np.asarray(views, float)
    op = get_operator(views)
    full = np.where(table.valid, table.rho, 0.0).T
    ks = strided_views(len(views), stride)
    out = np.empty((len(ks), 3))
    for i, k in enumerate(ks):
        cells, w = op.albedo_view(k)
        out[i] = full[cells].T @ np.asarray(w, dtype=float)
    return out
