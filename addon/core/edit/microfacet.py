"""The microfacet reading of a table (SPEC §3 "Editing", step 2).

A specular table is read as rho_s = F(theta_d) D(theta_h) G(wi, wo) / (4 cos_i cos_o) x residual.
D comes from the table itself: at the back-scattering cells (theta_d -> 0, wi = wo = h) the
reading gives rho_s = F0 D(h) / (4 A(h)^2) (separable Smith masking), with A(v) the projected
area of the microsurface toward v, itself an integral of D. So D is the fixed point of
D <- b A(D)^2, normalised by the area toward the normal (int D cos theta_m dw = 1, which is
A(n)); Dupuy et al. 2015. Masking follows from D through Smith: G1(v) = cos_v / A(v).

Everything the edit needs is in one per-cell quantity, the masking denominator
``gden = 4 cos_i cos_o / G`` (``core.microsurface.masking_denominator``): separable G gives 4 A_i A_o, height-correlated G = 1/(1 + L_i + L_o)
(L = A / cos - 1) gives 4 (A_i cos_o + A_o cos_i - cos_i cos_o). Both stay finite at the horizon,
where G / cos does not. The reading of a cell is then F(theta_d) D(theta_h) / gden.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..file.merl import N_CELLS, RES_PD, RES_TD, RES_TH
from ..microsurface import FORMS
from ..microsurface import masking_denominator as gden

HALF_PI = 0.5 * math.pi
N_AREA = 512  # the projected area is tabulated on this many view angles in [0, pi/2]
N_FINE = 4096  # the NDF's sub-samples (uniform in the table's theta_h index) for that integral
FIXED_POINT_STEPS = 15  # Dupuy et al. report 5-15; the GGX tables here settle to 1e-9 by 12

_GEOMETRY: dict = {}


def theta_h_centres():
    """The theta_h of the table's cell centres (RES_TH,), square-root spaced."""
    return ((np.arange(RES_TH) + 0.5) / RES_TH) ** 2 * HALF_PI


def cell_cosines():
    """cos theta_i and cos theta_o at every cell centre, each (RES_TH, RES_TD, RES_PD), from
    z = cos td cos th -/+ sin td sin th cos pd (the two directions of a cell; once per process)."""
    if "cos" not in _GEOMETRY:
        th = theta_h_centres()[:, None, None]
        td = ((np.arange(RES_TD) + 0.5) / RES_TD * HALF_PI)[None, :, None]
        pd = ((np.arange(RES_PD) + 0.5) / RES_PD * math.pi)[None, None, :]
        a = np.cos(td) * np.cos(th)
        b = np.sin(td) * np.sin(th) * np.cos(pd)
        _GEOMETRY["cos"] = (a - b, a + b)
    return _GEOMETRY["cos"]


_ALL = (slice(None), slice(None))


def cosines(sub=_ALL):
    ci, co = cell_cosines()
    return ci[:, sub[0], sub[1]], co[:, sub[0], sub[1]]


def _ring_integral(a, b):
    """int_0^2pi max(0, a cos(phi) + b) dphi for a >= 0, b >= 0 (elementwise)."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi0 = np.arccos(np.clip(-b / a, -1.0, 1.0))
        part = 2.0 * (a * np.sin(phi0) + b * phi0)
    return np.where(a <= b, 2.0 * math.pi * b, part)


def area_kernel():
    """K (N_AREA, RES_TH): A(theta_v) = K @ D for D given at the cell centres (linear in the
    index coordinate u = sqrt(theta / (pi/2)) * 90 between centres, flat beyond the first and
    last), integrated over the hemisphere of microfacet normals m. Material independent."""
    if "K" not in _GEOMETRY:
        theta_v = np.linspace(0.0, HALF_PI, N_AREA)
        u = (np.arange(N_FINE) + 0.5) / N_FINE * RES_TH  # midpoints of N_FINE equal steps in u
        du = RES_TH / N_FINE
        tm = (u / RES_TH) ** 2 * HALF_PI
        dtm = 2.0 * u / RES_TH**2 * HALF_PI * du
        sv, cv = np.sin(theta_v)[:, None], np.cos(theta_v)[:, None]
        fine = _ring_integral(sv * np.sin(tm)[None], cv * np.cos(tm)[None]) * (np.sin(tm) * dtm)[None]
        # The interpolation of centre values to the fine samples (u_k = k + 0.5).
        x = np.clip(u - 0.5, 0.0, RES_TH - 1.0)
        i0 = np.minimum(np.floor(x).astype(int), RES_TH - 2)
        f = x - i0
        P = np.zeros((N_FINE, RES_TH))
        P[np.arange(N_FINE), i0] = 1.0 - f
        P[np.arange(N_FINE), i0 + 1] += f
        _GEOMETRY["K"] = (theta_v, fine @ P)
    return _GEOMETRY["K"]


@dataclass
class ProjectedArea:
    """A(theta_v) of one microsurface, tabulated on ``theta`` (N_AREA points in [0, pi/2])."""

    theta: np.ndarray
    values: np.ndarray

    def at(self, cos_v, s: float = 1.0):
        """A_s at the given cos theta_v: the area of the microsurface with its slopes scaled by
        s, A_s(theta) = (cos theta / cos theta*) A(theta*), tan theta* = s tan theta."""
        c = np.clip(np.asarray(cos_v, float), 0.0, 1.0)
        if s == 1.0:
            area = np.interp(np.arccos(c), self.theta, self.values)
        else:
            sn = np.sqrt(np.maximum(1.0 - c * c, 0.0))
            r = np.sqrt(c * c + (s * sn) ** 2)  # cos theta / cos theta*
            theta_star = np.arctan2(s * sn, c)
            area = r * np.interp(theta_star, self.theta, self.values)
        # A microsurface shows at least a flat one's area toward v (Smith's Lambda >= 0): a
        # reading from a table that is not a microsurface (Phong) can dip below it, and the
        # height-correlated denominator would then change sign.
        return np.maximum(area, c)


def projected_area(d_centres) -> ProjectedArea:
    theta_v, K = area_kernel()
    return ProjectedArea(theta_v, K @ np.asarray(d_centres, float))


def ndf_from_backscatter(b, form: str, steps: int = FIXED_POINT_STEPS):
    """The NDF D (at the cell centres, normalised: A(n) = 1), its projected area, and the scale
    F0 with b = F0 D / gden(h, h), from back-scattering values ``b`` (RES_TH,) >= 0."""
    b = np.maximum(np.nan_to_num(np.asarray(b, float)), 0.0)
    ch = np.cos(theta_h_centres())
    theta_v, K = area_kernel()
    area_h = np.ones(RES_TH)  # A(h) starts as a smooth surface's
    d = b.copy()
    for _ in range(steps):
        d = b * gden(ch, ch, area_h, area_h, form)
        norm = float(K[0] @ d)  # A(n) = int D cos theta_m dw
        if not norm > 0.0:
            return None
        d /= norm
        area = ProjectedArea(theta_v, K @ d)
        area_h = area.at(ch)
    f0 = float(K[0] @ (b * gden(ch, ch, area_h, area_h, form)))
    return d, area, f0


@dataclass
class Reading:
    """The microfacet reading of a specular table: NDF and area (channel average), masking form,
    per-channel Fresnel over theta_d, and how well the reading fits the table."""

    form: str
    ndf: np.ndarray  # (RES_TH,) D at the theta_h centres, int D cos dw = 1
    area: ProjectedArea
    fresnel: np.ndarray  # (3, RES_TD) per channel, F(theta_d) including F0
    misfit: float  # weighted relative misfit of the reading over the well-measured cells
    _own_gden: np.ndarray | None = field(default=None, repr=False, compare=False)

    def gden_cells(self, s: float = 1.0):
        """The masking denominator at every cell of the table (RES_TH, RES_TD, RES_PD), for the
        microsurface with slopes scaled by ``s``; the table's own (s = 1), which every synthesis
        divides by, is computed once (read-only)."""
        if s == 1.0 and self._own_gden is not None:
            return self._own_gden
        ci, co = cell_cosines()
        out = gden(ci, co, self.area.at(ci, s), self.area.at(co, s), self.form)
        if s == 1.0:
            out.flags.writeable = False
            self._own_gden = out
        return out

    def model(self, s: float = 1.0):
        """F D_s / gden_s at every cell, per channel (3, RES_TH, RES_TD, RES_PD)."""
        return (self.fresnel[:, None, :, None] * scaled_ndf(self.ndf, s)[None, :, None, None]) / self.gden_cells(s)[
            None
        ]


def scaled_ndf(ndf, s: float):
    """D_s at the theta_h centres: D_s(theta) = D(theta') cos^4 theta' / (s^2 cos^4 theta),
    tan theta' = tan theta / s (slope space scaled by s), D read between centres as the
    operator reads the table (``catmull_rom_matrix``)."""
    th = theta_h_centres()
    u = np.sqrt(np.arctan(np.tan(th) / s) / HALF_PI) * RES_TH - 0.5
    return catmull_rom_matrix(u) @ np.asarray(ndf, float) * jacobian(th, s)


def catmull_rom_matrix(x):
    """W (RES_TH, RES_TH): row k interpolates centre values at the fractional index x[k]
    (Catmull-Rom; mirrored below 0, clamped at the last centre)."""
    x = np.clip(np.asarray(x, float), -0.5, RES_TH - 1.0)
    i0 = np.floor(x).astype(int)
    f = x - i0
    f2, f3 = f * f, f * f * f
    w = 0.5 * np.stack([-f + 2 * f2 - f3, 2 - 5 * f2 + 3 * f3, f + 4 * f2 - 3 * f3, f3 - f2])
    W = np.zeros((len(x), RES_TH))
    rows = np.arange(len(x))
    for k in range(4):
        j = i0 + k - 1
        j = np.where(j < 0, -1 - j, np.minimum(j, RES_TH - 1))
        np.add.at(W, (rows, j), w[k])
    return W


def jacobian(theta_h, s: float):
    """cos^4 theta' / (s^2 cos^4 theta) with tan theta' = tan theta / s, finite at pi/2."""
    c2 = np.cos(theta_h) ** 2
    return 1.0 / (s * s * (c2 + (1.0 - c2) / (s * s)) ** 2)


def fit_fresnel(spec, valid, base, min_cos: float = 0.1, sub=_ALL):
    """Per channel and theta_d row, the least-squares F with spec ~ F * base over valid cells
    whose two directions are at least ``min_cos`` above the horizon; rows without such cells
    take the nearest row's value. spec (3, TH, TD, PD), base (TH, TD, PD), on the rows and
    columns ``sub`` picks (theta_d, phi_d slices); F is returned for every row."""
    ci, co = cosines(sub)
    low = np.minimum(ci, co)

    def sums(use):
        w = np.where(use, base[None], 0.0)
        return np.einsum("chdp,chdp->cd", w, spec), np.einsum("chdp,hdp->cd", w, base)

    num, den = sums(valid & (low >= min_cos)[None])
    # Rows near theta_d = 90 deg have no cell that high above the horizon (at theta_h = 0 both
    # directions are at cos theta_d): there F is read from every cell above it, since F climbs
    # steeply there and the nearest well-measured row's value would miss it.
    num_all, den_all = sums(valid & (low > 0.0)[None])
    empty = den <= 1e-300
    num, den = np.where(empty, num_all, num), np.where(empty, den_all, den)
    out = np.zeros((spec.shape[0], RES_TD))
    rows = np.arange(RES_TD)[sub[0]]
    for c in range(spec.shape[0]):
        ok = den[c] > 1e-300
        if ok.any():
            out[c] = np.interp(np.arange(RES_TD), rows[ok], num[c, ok] / den[c, ok])
    return np.maximum(out, 0.0)


def _backscatter(spec_avg, valid_avg):
    """The back-scattering values per theta_h centre: the first theta_d row, averaged over phi_d
    where measured (theta_d = 0.5 deg, so phi_d hardly matters there)."""
    row = np.where(valid_avg[:, 0, :], spec_avg[:, 0, :], 0.0)
    n = valid_avg[:, 0, :].sum(axis=1)
    b = row.sum(axis=1) / np.maximum(n, 1)
    ok = n > 0
    if ok.any() and not ok.all():
        idx = np.arange(RES_TH)
        b = np.interp(idx, idx[ok], b[ok])
    return b


def misfit(spec, valid, model, sub=_ALL):
    """The reading's misfit: sum of w (spec - model)^2 / sum of w spec^2 over valid cells, with w
    = cos_i cos_o (grazing cells, the noisiest measured, count less). spec (C, TH, TD, PD)."""
    ci, co = cosines(sub)
    w = np.where(valid, (np.maximum(ci, 0.0) * np.maximum(co, 0.0))[None], 0.0)
    num = float(np.sum(w * (spec - model) ** 2))
    den = float(np.sum(w * spec**2))
    return num / den if den > 0.0 else math.inf


def _area_plan(sub):
    """Where each cell's two directions fall on the area's angle grid (index, fraction), for
    the cells ``sub`` picks: the cell cosines are fixed, so the lookup is planned once."""
    key = ("plan", repr(sub))
    if key not in _GEOMETRY:
        plans = []
        for c in cosines(sub):
            x = np.arccos(np.clip(c, 0.0, 1.0)) / HALF_PI * (N_AREA - 1)
            i0 = np.minimum(np.floor(x).astype(np.int32), N_AREA - 2)
            plans.append((i0, x - i0, c))
        _GEOMETRY[key] = plans
    return _GEOMETRY[key]


def _areas_at_cells(area, sub):
    """(A_i, A_o) at every cell of ``sub`` (as ``ProjectedArea.at`` with s = 1, planned)."""
    v = area.values
    return [np.maximum(v[i0] * (1.0 - f) + v[i0 + 1] * f, c) for i0, f, c in _area_plan(sub)]


def read_microfacets(spec, valid, forms=FORMS) -> Reading | None:
    """The microfacet reading of a specular table ``spec`` (C, N_CELLS) with mask ``valid``: the
    masking form that fits it better, or None when the table holds no lobe to read. The NDF is
    taken from the channel average. (The floor's search reads a subset of the cells against
    rho - kd unclipped: ``read_subset``.)"""
    spec = np.asarray(spec, float).reshape(-1, RES_TH, RES_TD, RES_PD)
    valid = np.asarray(valid, bool).reshape(-1, RES_TH, RES_TD, RES_PD)
    return read_subset(backscatter(spec[:, :, :1, :], valid[:, :, :1, :]), spec, valid, spec, forms)


def backscatter(spec_row0, valid_row0):
    """The back-scattering values of a specular table from its first theta_d row alone, (C, TH,
    1, PD) each: ``read_subset``'s ``b``."""
    return _backscatter(spec_row0.mean(axis=0), valid_row0.all(axis=0))


def read_subset(b, spec, valid, judge, forms=FORMS, sub=_ALL) -> Reading | None:
    """``read_microfacets`` on the cells ``sub`` picks, already picked: ``b`` the back-scattering
    values (``backscatter``), ``spec``, ``valid`` and ``judge`` (0 where missing) on ``sub``'s
    cells. The floor's search calls it directly, so that each of its steps touches only them."""
    best = None
    ci, co = cosines(sub)
    for form in forms:
        got = ndf_from_backscatter(b, form)
        if got is None:
            continue
        d, area, _ = got
        area_i, area_o = _areas_at_cells(area, sub)
        base = d[:, None, None] / gden(ci, co, area_i, area_o, form)
        fres = fit_fresnel(spec, valid, base, sub=sub)
        r = Reading(form, d, area, fres, math.inf)
        r.misfit = misfit(judge, valid, fres[:, None, sub[0], None] * base[None], sub)
        if best is None or r.misfit < best.misfit:
            best = r
    return best


def flat(cube):
    """(C, TH, TD, PD) -> (C, N_CELLS) in MERL's order."""
    return np.asarray(cube).reshape(-1, N_CELLS)
