"""The roughness operator (SPEC §3 "Editing", step 3): the microsurface's slopes scaled by s.

With the reading rho_s = F(theta_d) D(theta_h) / gden (``microfacet``), scaling slope space by s
changes D to D_s(theta) = D(theta') cos^4 theta' / (s^2 cos^4 theta), tan theta' = tan theta / s,
and the masking to that of D_s. Every cell of the edited table is read from the source cell
(theta_h', theta_d, phi_d):

    rho_s'(cell) = J(theta_h) * Q(theta_h', theta_d, phi_d) / gden_s(cell),  Q = rho_s * gden,

J the Jacobian above. Q is the table without its masking (F D x residual): it is interpolated
along theta_h (Catmull-Rom in the index coordinate u = sqrt(theta_h / (pi/2)) * 90 - 1/2, even
about theta_h = 0), and where the source is missing (beyond the table's horizon, reached when
narrowing) it is completed by the reading itself, Q = F D. F and the residual are carried
unchanged. Built cell by cell in (theta_h, theta_d, phi_d), the table is reciprocal; s = 1 gives
the input back exactly.

Near the horizon a measured table can fall off faster than any reading (the measurement goes to
zero, the model does not): within a few degrees of it the edit fades to the cell's own value
times the reading's growth for that cell, so no cell there grows beyond what the microsurface
predicts for it from its own measurement (on an analytic table the two agree to 1e-9 in the
reading's misfit; capping those cells at the lobe's peak instead broke that agreement on a
widened GGX plastic and with it the next edit's masking form and floor).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..limits import ROUGHNESS_RANGE
from ..merl import RES_PD, RES_TD, RES_TH, MerlTable
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


@dataclass
class Source:
    """What every edit of one table reads (made once per analysis): the floor, the reading, the
    masking-free values Q (completed where missing) and the table's own specular part."""

    table: MerlTable
    kd: np.ndarray  # (3,) the edit's floor
    floor_scale: np.ndarray  # (3,) kd / kd_paper
    reading: Reading
    spec: np.ndarray  # (3, TH, TD, PD) rho - kd, clipped at 0, 0 where missing
    q: np.ndarray  # (3, TH, TD, PD) spec * gden, completed by F D where missing
    peak: np.ndarray  # (3,) the largest specular value per channel


def prepare(table: MerlTable, kd_paper, split=True) -> Source | None:
    """The edit's view of ``table``: its floor (``floor.joint_floor``, bounded by ``kd_paper``),
    microfacet reading and Q. None when there is no lobe to read."""
    kd, t = joint_floor(table, kd_paper) if split else (np.zeros(3), np.zeros(3))
    valid = table.valid.reshape(CUBE)
    spec = np.maximum(table.rho.reshape(CUBE) - kd[:, None, None, None], 0.0) * valid
    reading = read_microfacets(spec, valid)
    if reading is None:
        return None
    gd = reading.gden_cells()
    model_q = reading.fresnel[:, None, :, None] * reading.ndf[None, :, None, None]
    q = np.where(valid, spec * gd[None], model_q)
    peak = spec.reshape(3, -1).max(axis=1)
    return Source(table, kd, t, reading, spec, q, peak)


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
    spec = q / src.reading.gden_cells(s)[None]
    faded = 0
    if fade:
        spec, faded = _horizon_fade(src, s, spec)
    spec = np.maximum(np.nan_to_num(spec, nan=0.0, posinf=0.0, neginf=0.0), 0.0)  # finite, nonnegative
    rho = np.where(valid, spec + src.kd[:, None, None, None], 0.0)
    return MerlTable(rho.reshape(3, -1), table.valid.copy(), None), {"faded_cells": int(faded)}


def _horizon_fade(src: Source, s, spec):
    """Within FADE_COS of the horizon the edited cell fades to the source cell times the
    reading's own growth for it (model_s / model): where a measured table falls off faster than
    its reading, the cell keeps its own fall-off instead of taking the reading's."""
    ci, co = cell_cosines()
    low = np.minimum(ci, co)
    x = np.clip((low - FADE_COS[0]) / (FADE_COS[1] - FADE_COS[0]), 0.0, 1.0)
    w = x * x * (3.0 - 2.0 * x)  # smoothstep: the map from s to the table stays smooth
    near = w < 1.0
    if not near.any():
        return spec, 0
    r = src.reading
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        d_ratio = scaled_ndf(r.ndf, s) / np.maximum(r.ndf, 1e-300)
        m_ratio = d_ratio[:, None, None] * (r.gden_cells(1.0) / r.gden_cells(s))
    kept = src.spec * np.nan_to_num(m_ratio, nan=0.0, posinf=0.0)[None]
    # Where the reading's NDF has (almost) nothing, its growth ratio means nothing (a cell of
    # rounding noise times 1e300): those theta_h rows keep the operator's own value.
    trusted = r.ndf > 1e-6 * float(r.ndf.max(initial=0.0))
    w = np.where(trusted[:, None, None], w, 1.0)
    near = w < 1.0
    out = np.where(near[None], w[None] * spec + (1.0 - w[None]) * kept, spec)
    return out, int(near.sum())
