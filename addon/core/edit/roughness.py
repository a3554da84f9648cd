"""The roughness operator (SPEC §3 "Editing", step 3): the microsurface's slopes scaled by s.

With the reading rho_s = F(theta_d) D(theta_h) / gden (``microfacet``), scaling slope space by s
changes D to D_s(theta) = D(theta') cos^4 theta' / (s^2 cos^4 theta), tan theta' = tan theta / s,
and the masking to that of D_s. Every cell of the edited table is read from the source cell
(theta_h', theta_d, phi_d):

    rho_s'(cell) = J(theta_h) * Q(theta_h', theta_d, phi_d) / gden_s(cell),  Q = rho_s * gden,

J the Jacobian above. Q is the table without its masking (F D x residual): it is interpolated
along theta_h (Catmull-Rom in the index coordinate u = sqrt(theta_h / (pi/2)) * 90 - 1/2, even
about theta_h = 0), and where the source is missing (beyond the table's horizon, reached when
narrowing) it is completed by the reading, Q = F D times the table's own ratio to it at the
column's last measured cell (a table that falls off faster than its reading keeps falling). F and
the residual are carried unchanged. Built cell by cell in (theta_h, theta_d, phi_d), the table is reciprocal; s = 1 gives
the input back exactly.

Near the horizon a measured table can fall off faster than any reading (the measurement goes to
zero, the model does not): within a few degrees of it the edit fades to the cell's own value
times the reading's growth for that cell (never above the operator's own value), so no cell
there grows beyond what the microsurface predicts for it from its own measurement (on an
analytic table the two agree to 1e-9 in the reading's misfit; capping those cells at the lobe's
peak instead broke that agreement on a widened GGX plastic and with it the next edit's masking
form and floor).

A passive surface returns at most the light it receives. Where the reading cannot explain a
table at grazing views (a fabric's sheen read as a Fresnel factor far above 1, held down in the
source by its broad masking), narrowing relieves that masking and the transported values would
return several times the light received (satin_blue at s = 0.45: albedo 7.2 at 87 deg). So the
edited specular part is scaled by c(theta_i) c(theta_o), which keeps it reciprocal, so that no
analysed view's albedo exceeds max(1, the source's own albedo at that view); c = 1 wherever the
bound holds, so microfacet tables, which keep their energy below it, are untouched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..file.merl import RES_PD, RES_TD, RES_TH, MerlTable
from ..limits import ROUGHNESS_RANGE
from ..profiles.integrate import default_views, directional_albedo, get_operator, strided_views
from .floor import joint_floor
from .microfacet import (
    HALF_PI,
    Reading,
    catmull_rom_matrix,
    cell_cosines,
    jacobian,
    read_microfacets,
    scaled_ndf,
    theta_h_centres,
)

S_RANGE = ROUGHNESS_RANGE  # the roughness scales the operator takes
FADE_COS = (0.01, 0.06)  # the horizon fade's band in cos of the lower direction (0.6 to 3.4 deg)
CUBE = (3, RES_TH, RES_TD, RES_PD)
# The bound's quick look, on every synthesis: every third analysed view and the last (0.035 s,
# against 0.1 s for all 90, three to five times an Apply); below this share of the bound there,
# no view between them reaches it.
ENERGY_STRIDE = 3
ENERGY_MARGIN = 0.9
ENERGY_CHUNK = 10  # views per step of the exact bound's sums


@dataclass
class Source:
    """What every edit of one table reads (made once per analysis): the floor, the reading, the
    masking-free values Q (completed where missing) and the table's own specular part."""

    table: MerlTable
    kd: np.ndarray  # (3,) the edit's floor
    floor_scale: np.ndarray  # (3,) kd / kd_paper
    reading: Reading
    spec: np.ndarray  # (3, TH, TD, PD) rho - kd, clipped at 0, 0 where missing
    q: np.ndarray  # (3, TH, TD, PD) spec * gden; where missing, F D times the column's last ratio
    peak: np.ndarray  # (3,) the largest specular value per channel
    views: np.ndarray  # the analysis's view elevations (the energy bound's views)
    albedo: np.ndarray  # (views, 3) the table's own directional albedo
    floor_albedo: np.ndarray  # (views, 3) the floor's share of it
    # The table's own (profiles, fit) as ``scale.measure`` makes them, by (views, split): an
    # edit at s = 1 (a mean-slope move alone) and the region both need it (``scale.own``).
    measured: dict = field(default_factory=dict, repr=False)


def prepare(table: MerlTable, kd_paper, split=True, views=None) -> Source | None:
    """The edit's view of ``table``: its floor (``floor.joint_floor``, bounded by ``kd_paper``),
    microfacet reading and Q, and its albedo at ``views`` (the analysis's; default views when
    None). None when there is no lobe to read."""
    kd, t = joint_floor(table, kd_paper) if split else (np.zeros(3), np.zeros(3))
    valid = table.valid.reshape(CUBE)
    spec = np.maximum(table.rho.reshape(CUBE) - kd[:, None, None, None], 0.0) * valid
    reading = read_microfacets(spec, valid)
    if reading is None:
        return None
    gd = reading.gden_cells()
    model_q = reading.fresnel[:, None, :, None] * reading.ndf[None, :, None, None]
    q = np.where(valid, spec * gd[None], _complete(spec * gd[None], model_q, valid))
    peak = spec.reshape(3, -1).max(axis=1)
    views = default_views() if views is None else np.asarray(views, float)
    albedo = directional_albedo(table, views)
    ones = MerlTable(np.where(table.valid, 1.0, 0.0), table.valid, None)
    floor_albedo = directional_albedo(ones, views) * kd[None, :]
    return Source(table, kd, t, reading, spec, q, peak, views, albedo, floor_albedo)


def _complete(q, model_q, valid):
    """Q where the table is missing (beyond its horizon, read when narrowing): the reading's F D
    times the table's own ratio to it at the column's last measured theta_h, so a table that
    falls off faster than its reading near the horizon keeps falling there."""
    idx = np.arange(RES_TH)[None, :, None, None]
    last = np.maximum.accumulate(np.where(valid, idx, -1), axis=1)  # last measured row at or below
    have = last >= 0
    at = np.take_along_axis(q, np.maximum(last, 0), axis=1)
    model_at = np.take_along_axis(np.broadcast_to(model_q, q.shape), np.maximum(last, 0), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(model_at > 0.0, at / model_at, 1.0)
    return model_q * np.where(have, np.clip(np.nan_to_num(ratio, nan=1.0, posinf=1.0), 0.0, 1.0), 1.0)


def source_index(s: float):
    """The fractional theta_h index of each centre's source, theta_h' = atan(tan theta_h / s)."""
    th = theta_h_centres()
    return np.sqrt(np.arctan(np.tan(th) / s) / HALF_PI) * RES_TH - 0.5


def scale_roughness(src: Source, s: float, fade: bool = True) -> tuple[MerlTable, dict]:
    """The table of the same material with its slopes scaled by ``s``; and a report (capped
    cells). Never modifies the source."""
    if not (S_RANGE[0] <= s <= S_RANGE[1]) or not math.isfinite(s):
        raise ValueError(f"roughness scale {s!r} outside {S_RANGE[0]} .. {S_RANGE[1]}")
    table = src.table
    if s == 1.0:
        out = table.copy()
        out.path = None
        return out, {"faded_cells": 0}
    W = catmull_rom_matrix(source_index(s))
    th = theta_h_centres()
    valid = table.valid.reshape(CUBE)
    q = np.einsum("hk,ckdp->chdp", W, src.q, optimize=True)
    np.maximum(q, 0.0, out=q)
    q *= jacobian(th, s)[None, :, None, None]
    gden_s = src.reading.gden_cells(s)
    spec = q / gden_s[None]
    faded = 0
    if fade:
        spec, faded = _horizon_fade(src, s, spec, gden_s)
    spec = np.maximum(np.nan_to_num(spec, nan=0.0, posinf=0.0, neginf=0.0), 0.0)  # finite, nonnegative
    spec = np.where(valid, spec, 0.0)
    bounded = _energy_bound(src, spec)
    rho = np.where(valid, spec + src.kd[:, None, None, None], 0.0)
    return MerlTable(rho.reshape(3, -1), table.valid.copy(), None), {
        "faded_cells": int(faded),
        "energy_bounded_views": bounded,
    }


def _energy_bound(src: Source, spec) -> int:
    """Scale ``spec`` (3, TH, TD, PD, in place) so that no analysed view's albedo, floor
    included, exceeds max(1, the source's there); returns how many view-channel pairs needed it.

    A cell is scaled by c(theta_i) c(theta_o) (symmetric, so the table stays reciprocal), c read
    linearly between nodes at every other analysed view. With E[k, n, m] the albedo of view k
    that cells put on nodes n (theta_i) and m (theta_o), view k's albedo is c^T E[k] c exactly,
    so c is solved on that small array: multiplicative steps move each node's c towards what
    its views allow, up to 1, which it keeps wherever the bound holds.

    E >= 0 and c <= 1, so a view within its bound at c = 1 stays within it whatever c is, and a
    node whose views are all within keeps c = 1 through every step (each view's headroom is
    at least 1). So E is summed only for the views of nodes that own a view over the bound, in
    the channels that have one: the same c as from every view's E. A table far below its bound
    on every third view (the usual case) pays only that look; one near it, every view's
    albedo too."""
    views = np.asarray(src.views, float)
    limit = np.maximum(np.maximum(src.albedo, 1.0) - src.floor_albedo, 0.0)  # (V, 3)
    valid = src.table.valid
    flat = spec.reshape(3, -1)
    table = MerlTable(flat, valid, None)
    checked = strided_views(len(views), ENERGY_STRIDE)
    if np.all(directional_albedo(table, views, ENERGY_STRIDE) <= ENERGY_MARGIN * limit[checked]):
        return 0  # far below the bound on every third view: no view between them reaches it
    a = directional_albedo(table, views)
    # E's sums are this albedo to float32 rounding (its corner weights): a view this close to
    # its bound is summed too, so E alone decides which views are over, as it always has.
    near = a > limit * (1.0 - 1e-5)
    if not near.any():
        return 0
    op = get_operator(views)
    nv = len(views)
    (ni, fi), (no, fo), owner, nn = _cell_nodes(views)
    channels = [ch for ch in range(3) if near[:, ch].any()]
    busy = np.zeros(nn, bool)
    busy[owner[near.any(axis=1)]] = True
    need = busy[owner]  # (V,) the views the solve's steps read
    masked = np.where(valid, flat, 0.0)
    Es = np.zeros((3, nv * nn * nn))
    # A few views at a time: each numpy call stays short, so a worker thread doing this (the
    # live preview) never holds the GIL long enough to stall Blender's window.
    for k0, k1 in _runs(need, ENERGY_CHUNK):
        first, last = int(op.offsets[k0]), int(op.offsets[k1])
        cells = op.cells[first:last]
        base = np.repeat(np.arange(k1 - k0, dtype=np.int32) * (nn * nn), np.diff(op.offsets[k0 : k1 + 1]))
        rows = slice(k0 * nn * nn, k1 * nn * nn)
        nie, fie, noe, foe, alb = ni[cells], fi[cells], no[cells], fo[cells], op.albedo[first:last]
        vals = masked[:, cells]
        for di, wi in ((0, 1.0 - fie), (1, fie)):
            for do, wo in ((0, 1.0 - foe), (1, foe)):
                idx = base + np.minimum(nie + di, nn - 1) * nn + np.minimum(noe + do, nn - 1)
                w = (wi * wo) * alb
                for ch in channels:
                    Es[ch, rows] += np.bincount(idx, vals[ch] * w, (k1 - k0) * nn * nn)
    bounded = 0
    for ch in channels:
        E = Es[ch]
        E = E.reshape(nv, nn, nn)
        lim = limit[:, ch]
        if np.all(E.sum(axis=(1, 2)) <= lim):
            continue
        c = _solve_scales(E, lim, owner, nn)
        bounded += int((E.sum(axis=(1, 2)) > lim).sum())
        flat[ch] *= _at_cells(c, ni, fi) * _at_cells(c, no, fo)
    return bounded


def _runs(mask, longest):
    """(start, stop) of the runs of True in ``mask``, none longer than ``longest``."""
    out, k, n = [], 0, len(mask)
    while k < n:
        if not mask[k]:
            k += 1
            continue
        stop = k
        while stop < n and mask[stop] and stop - k < longest:
            stop += 1
        out.append((k, stop))
        k = stop
    return out


def bound_energy(src: Source, table: MerlTable) -> tuple[MerlTable, int]:
    """``table`` (an edit of ``src``'s table over the same floor, such as the tilt's) with the
    same passivity bound as ``scale_roughness`` applies: no analysed view's albedo above
    max(1, the source's). Returns the table (``table`` itself when nothing was over) and how
    many view-channel pairs needed it."""
    kd = src.kd[:, None, None, None]
    valid = table.valid.reshape(CUBE)
    spec = np.where(valid, np.maximum(table.rho.reshape(CUBE) - kd, 0.0), 0.0)
    bounded = _energy_bound(src, spec)
    if not bounded:
        return table, 0
    rho = np.where(valid, spec + kd, 0.0)
    return MerlTable(rho.reshape(3, -1), table.valid.copy(), None), bounded


def _at_cells(c, node, frac):
    return c[node] * (1.0 - frac) + c[np.minimum(node + 1, len(c) - 1)] * frac


def _solve_scales(E, lim, owner, nn, steps=80):
    """The node scales c in [0, 1] with c^T E[k] c <= lim[k] for every view k, each as large as
    its views allow: each node moves by the square root of its tightest view's headroom (the
    albedo is quadratic in c near a view's own node), then, if any view is still over, only
    downwards until none is."""
    c = np.ones(nn)
    albedo = lambda c: np.einsum("knm,n,m->k", E, c, c)  # noqa: E731
    for step in range(2 * steps):
        a = albedo(c)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(a > 0.0, lim / a, np.inf)
        if step >= steps and np.all(r >= 1.0 - 1e-9):
            break
        worst = np.full(nn, np.inf)
        np.minimum.at(worst, owner, r)
        if step >= steps:
            worst = np.minimum(worst, 1.0)
        c = np.clip(c * np.sqrt(np.minimum(worst, 4.0)), 0.0, 1.0)
    # Whatever remains over (a view whose own nodes are already at 0), scale the lot down.
    a = albedo(c)
    over = a > lim
    if over.any():
        c *= math.sqrt(float(np.min(lim[over] / a[over])))
    return c


def _cell_nodes(views):
    """The energy bound's nodes (every other view and the last) and, for each cell, where its
    theta_i and theta_o fall among them (lower node, fraction towards the next); ``owner``:
    each view's nearest node. Material independent, kept for the last set of views."""
    key = np.asarray(views, float).tobytes()
    if _NODES.get("key") != key:
        v = np.asarray(views, float)
        keep = strided_views(len(v), 2)
        nodes = v[keep]
        nn = len(nodes)

        def place(cos):
            t = np.arccos(np.clip(cos, 0.0, 1.0)).ravel()
            i0 = np.clip(np.searchsorted(nodes, t, side="right") - 1, 0, nn - 1)
            nxt = np.minimum(i0 + 1, nn - 1)
            span = nodes[nxt] - nodes[i0]
            f = np.where(span > 0, np.clip((t - nodes[i0]) / np.where(span > 0, span, 1.0), 0.0, 1.0), 0.0)
            return i0.astype(np.int32), f.astype(np.float32)

        ci, co = cell_cosines()
        owner = np.abs(v[:, None] - nodes[None, :]).argmin(axis=1)
        _NODES.update(key=key, value=(place(ci), place(co), owner, nn))
    return _NODES["value"]


_NODES: dict = {}


def _fade_band():
    """The horizon band's cells (flat indices into (RES_TH, RES_TD, RES_PD)), their theta_h
    rows and fade weights w (0 at the horizon, 1 at the band's inner edge): a few percent of
    the table, material independent, so the fade reads and writes only them."""
    if "band" not in _NODES:
        ci, co = cell_cosines()
        low = np.minimum(ci, co).ravel()
        x = np.clip((low - FADE_COS[0]) / (FADE_COS[1] - FADE_COS[0]), 0.0, 1.0)
        w = x * x * (3.0 - 2.0 * x)  # smoothstep: the map from s to the table stays smooth
        idx = np.flatnonzero(w < 1.0)
        _NODES["band"] = (idx, idx // (RES_TD * RES_PD), w[idx])
    return _NODES["band"]


def _horizon_fade(src: Source, s, spec, gden_s):
    """Within FADE_COS of the horizon the edited cell fades to the source cell times the
    reading's own growth for it (model_s / model): where a measured table falls off faster than
    its reading, the cell keeps its own fall-off instead of taking the reading's. ``gden_s``:
    the scaled surface's masking denominator at every cell."""
    idx, rows, w = _fade_band()
    r = src.reading
    # Where the reading's NDF has (almost) nothing, its growth ratio means nothing (a cell of
    # rounding noise times 1e300): those theta_h rows keep the operator's own value.
    trusted = r.ndf > 1e-6 * float(r.ndf.max(initial=0.0))
    near = trusted[rows]
    idx, rows, w = idx[near], rows[near], w[near]
    if not len(idx):
        return spec, 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        d_ratio = scaled_ndf(r.ndf, s) / np.maximum(r.ndf, 1e-300)
        m_ratio = d_ratio[rows] * (r.gden_cells(1.0).ravel()[idx] / gden_s.ravel()[idx])
    flat = spec.reshape(3, -1)
    kept = src.spec.reshape(3, -1)[:, idx] * np.nan_to_num(m_ratio, nan=0.0, posinf=0.0)[None]
    # The fade only keeps a faster fall-off: it never raises a cell above the operator's own value
    # (where the reading's NDF is tiny but above the trust cut, its growth ratio blew up: a
    # Phong table widened x1.4 got a grazing cell 621 times the lobe's peak).
    own = flat[:, idx]
    flat[:, idx] = w * own + (1.0 - w) * np.minimum(kept, own)
    return spec, int(len(idx))
