"""The edit's diffuse floor (SPEC §3 "Editing", step 1).

The paper's floor (the minimum of the 45 deg slice, ``profiles.diffuse_floor``) holds lobe tail
on a plastic: a roughness edit through it carries that tail as if it were diffuse. The edit's
floor is instead the one under which the rest of the table is best read as microfacets: per
channel kd = t * kd_paper, t in [0, 1], minimising the misfit of rho - kd against its own
microfacet reading (``microfacet.read_microfacets``) over a subset of the cells. The misfit is
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


def floor_misfit(rho_c, valid_c, kd_c, sub=SUBSET, forms=FORMS):
    """The misfit of one channel's rho - kd_c against its microfacet reading, in absolute terms
    (sum of cos_i cos_o (rho - kd - reading)^2), and the masking form read (inf, None: no lobe).
    Absolute, not relative to the lobe's own energy: a floor left in the lobe adds energy the
    reading explains well, and a relative misfit rewarded that (a Phong lobe over a Lambertian
    0.1 read its floor as 0, and every edit then spread the diffuse as lobe tail).
    rho_c, valid_c: (RES_TH, RES_TD, RES_PD)."""
    spec = np.maximum(rho_c - kd_c, 0.0) * valid_c
    judge = rho_c - kd_c
    r = M.read_microfacets(spec[None], valid_c[None], forms=forms, sub=sub, judge=judge[None])
    if r is None:
        return math.inf, None
    ci, co = M.cosines(sub)
    j = np.where(valid_c[:, sub[0], sub[1]], judge[:, sub[0], sub[1]], 0.0)
    w = np.maximum(ci, 0.0) * np.maximum(co, 0.0)
    return r.misfit * float(np.sum(w * j * j)), r.form


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


def joint_floor(table, kd_paper):
    """(kd per channel, multipliers t per channel): the floor under which each channel's lobe
    reads best as microfacets, at most the paper's floor ``kd_paper``."""
    kd_paper = np.maximum(np.nan_to_num(np.asarray(kd_paper, float)), 0.0)
    cube = (3, M.RES_TH, M.RES_TD, M.RES_PD)
    rho = np.asarray(table.rho, float).reshape(cube)
    valid = np.asarray(table.valid, bool).reshape(cube)
    kd = np.zeros(3)
    ts = np.zeros(3)
    for c in range(3):
        if kd_paper[c] <= 0.0:
            continue
        # Both masking forms at every step: which one the table has shows only near its true
        # floor (a height-correlated GGX plastic read at the paper's floor fits separable better).
        cache: dict = {}

        def f(t, c=c, cache=cache):
            if t not in cache:
                cache[t] = floor_misfit(rho[c], valid[c], t * kd_paper[c])[0]
            return cache[t]

        grid = np.linspace(0.0, 1.0, COARSE)
        coarse = [f(t) for t in grid]
        k = int(np.argmin(coarse))
        if not np.isfinite(coarse[k]):
            continue
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, COARSE - 1)]
        best = min([(coarse[k], grid[k]), _golden(f, lo, hi, SEARCH_STEPS)])
        ts[c] = best[1]
        kd[c] = ts[c] * kd_paper[c]
    return kd, ts
