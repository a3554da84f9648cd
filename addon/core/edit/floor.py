"""The edit's diffuse floor (SPEC §3 "Editing", step 1).

The paper's floor (the minimum of the 45 deg slice, ``profiles.diffuse_floor``) holds lobe tail
on a plastic: a roughness edit through it carries that tail as if it were diffuse. The edit's
floor is instead the one under which the rest of the table is best read as microfacets: per
channel kd = t * kd_paper, t in [0, 1], minimising the misfit of rho - kd against its own
microfacet reading (``microfacet.read_subset``) over a subset of the cells. The misfit is
taken on rho - kd itself, not on its positive part: a floor above the true one leaves cells
below it, which no reading explains, so it is not rewarded for cutting the lobe's tail off.
Bounded above by the paper's floor: on measured tables the joint fit is less reliable, and a
floor above the table's own minimum would cut into it.
"""

from __future__ import annotations

import math

import numpy as np

from ..microsurface import FORMS
from . import microfacet as M

# The search reads every 3rd theta_d row (row 0, the back-scattering one, included) and every
# 4th phi_d column: 1/12 of the cells.
SUBSET = (slice(0, None, 3), slice(0, None, 4))
COARSE = 6  # t on a coarse grid first (the misfit need not be unimodal over [0, 1])
SEARCH_STEPS = 20  # then golden-section steps around the best two grid steps: t to 3e-5
GOLD = (math.sqrt(5.0) - 1.0) / 2.0
# Not Brent's search: it reads half as many cells, but near the true floor the misfit has a
# shallow dip beside a sharp one (the masking form read switches), and on the rule bench's GGX
# plastic at 0.08 its parabolic steps settled in the shallow one (t 0.9968 against 0.9985; the
# widened table 11 % off in variance), where the golden steps find the sharp one.
# The golden steps' resolution at a bound (a bracket of one grid step, 0.2 * GOLD^20 = 1.3e-5):
# where the coarse grid's best is a bound and the misfit still falls this close to it, the
# minimum is at the bound to that resolution, and the steps would only creep towards it.
EDGE = 1e-5


class _Cells:
    """One channel's cells the search reads, picked once: the first theta_d row (the NDF's
    back-scattering values) and the subset ``sub`` (the misfit's), each step subtracting its
    floor from these alone rather than from the whole channel."""

    def __init__(self, rho_c, valid_c, sub=SUBSET):
        self.sub = sub
        self.rho0, self.valid0 = rho_c[None, :, :1, :], valid_c[None, :, :1, :]
        self.rho, self.valid = rho_c[None, :, sub[0], sub[1]], valid_c[None, :, sub[0], sub[1]]
        ci, co = M.cosines(sub)
        self.w = np.maximum(ci, 0.0) * np.maximum(co, 0.0)

    def misfit(self, kd_c):
        """The misfit of rho - kd_c against its microfacet reading, in absolute terms (sum of
        cos_i cos_o (rho - kd - reading)^2), and the masking form read (inf, None: no lobe).
        Absolute, not relative to the lobe's own energy: a floor left in the lobe adds energy the
        reading explains well, and a relative misfit rewarded that (a Phong lobe over a
        Lambertian 0.1 read its floor as 0, and every edit then spread the diffuse as lobe tail)."""
        judge = np.where(self.valid, self.rho - kd_c, 0.0)
        b = M.backscatter(np.maximum(self.rho0 - kd_c, 0.0) * self.valid0, self.valid0)
        r = M.read_subset(b, np.maximum(judge, 0.0), self.valid, judge, FORMS, self.sub)
        if r is None:
            return math.inf, None
        return r.misfit * float(np.sum(self.w * judge[0] * judge[0])), r.form


def _golden(f, lo, hi, steps):
    a, b = hi - GOLD * (hi - lo), lo + GOLD * (hi - lo)
    fa, fb = f(a), f(b)
    for _ in range(steps):
        if fa <= fb:
            hi, b, fb = b, a, fa
            a = hi - GOLD * (hi - lo)
            fa = f(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + GOLD * (hi - lo)
            fb = f(b)
    return (fa, a) if fa <= fb else (fb, b)


def channel_floor(rho_c, valid_c, kd_paper_c) -> float:
    """t in [0, 1] for one channel: the multiple of its paper's floor under which the rest
    reads best as microfacets (0 when there is no lobe to read)."""
    # Both masking forms at every step: which one the table has shows only near its true floor
    # (a height-correlated GGX plastic read at the paper's floor fits separable better).
    cache: dict = {}
    cells = _Cells(rho_c, valid_c)

    def f(t):
        if t not in cache:
            cache[t] = cells.misfit(t * kd_paper_c)[0]
        return cache[t]

    grid = np.linspace(0.0, 1.0, COARSE)
    coarse = [f(t) for t in grid]
    k = int(np.argmin(coarse))
    if not np.isfinite(coarse[k]):
        return 0.0
    if k in (0, COARSE - 1) and f(grid[k] + (EDGE if k == 0 else -EDGE)) > coarse[k]:
        return float(grid[k])  # most measured tables: the paper's floor (t = 1) or none (t = 0)
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, COARSE - 1)]
    return float(min([(coarse[k], grid[k]), _golden(f, lo, hi, SEARCH_STEPS)])[1])


def joint_floor(table, kd_paper):
    """(kd per channel, multipliers t per channel): the floor under which each channel's lobe
    reads best as microfacets, at most the paper's floor ``kd_paper``. The channels one after
    another: side by side on two threads the search took longer (its steps are short numpy
    calls, which hold the GIL between them: ggx_glossy 1.36 s in order, 2.16 s on two)."""
    kd_paper = np.maximum(np.nan_to_num(np.asarray(kd_paper, float)), 0.0)
    cube = (3, M.RES_TH, M.RES_TD, M.RES_PD)
    rho = np.asarray(table.rho, float).reshape(cube)
    valid = np.asarray(table.valid, bool).reshape(cube)
    ts = np.array([channel_floor(rho[c], valid[c], kd_paper[c]) if kd_paper[c] > 0.0 else 0.0 for c in range(3)])
    return ts * kd_paper, ts
