"""Reciprocal-by-construction synthesis: the specular table transformed in (theta_h, theta_d, phi_d).

A MERL table is a function of the half/difference angles with phi_d folded, so any table built
cell by cell in that domain is reciprocal: nothing is averaged between the two views a cell
belongs to. The transform, per channel c:

    rho'(h, d, p) = G_c(d) * exp(q(d) L(h, d, p)) / s(d)^2 * rho_spec(h / s(d), d, p) + kd_c

- s(d): a width scale of theta_h (the lobe's width, hence the views' variances);
- exp(q L), L = log(cos th_i cos th_o / cos^2 th_d): a reciprocal tilt (1 at the mirror) that
  moves every view's mean toward (q > 0) or away from the normal; q = q~ / V(d) so that q~ is in
  radians of shift per unit of the tilt's slope;
- G_c(d): energy gains (the 1/s^2 keeps a small lobe's energy as its width changes).

Near the specular lobe theta_d ~ theta_o, so controls indexed by theta_d act almost per view.
Each is a hat spline over theta_d (KNOTS knots) added to a per-view start, solved by a fixed
number (STEPS) of damped Gauss-Newton steps on every view's re-measured energy, mean and average
variance, with a pseudo-Huber loss and a smoothness penalty across knots; the per-channel gains
are then a linear least-squares fit of every view's energy. The sensitivities are exact: the profile operator is linear in the table's values
(sums = weights @ values), so d sums / d control = weights @ (d values / d control).
A fixed number of steps from a fixed start, with fixed damping: the map from sliders to table
is continuous (no bisection, no picking among rounds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..file.merl import RES_PD, RES_TD, RES_TH, MerlTable, cell_centres
from ..geometry import directions_from_half_diff
from ..profiles.compute import specular_part
from ..profiles.integrate import SliceOperator
from ..threads import parallel_map

# Operator columns used by the solve: 1, x, phi, x^2, phi^2 (exponents(4) order: 0, 1, 2, 3, 5).
_COLS = (0, 1, 2, 3, 5)
STEPS = 8  # 12 gave the same per-view figures on 7 materials x 4 edits (BENCHMARKS), 0.4 s slower
KNOTS = 16
# Residual units: the SPEC §6 tolerances (log energy, mean in rad, log variance).
UNITS = np.array([0.02, 0.02, 0.02])
# Smoothness across theta_d rings (second differences), in the controls' own units.
SMOOTH = np.array([0.05, 0.05, 0.05])  # log s, q~, log G
DAMPING = 0.3
GAIN_DAMPING = 1e-3
ROBUST = 3.0  # residual (in UNITS) beyond which a view's pull stops growing
LOG_S_RANGE = (-2.3, 1.2)  # width scale 0.1 .. 3.3
Q_RANGE = (-4.0, 4.0)
MAX_STEP = 0.5  # trust region: the largest change of any control in one step
TILT_MAX = 3.0  # the tilt may raise a cell by at most e^3 (cells at the horizon)


_GEOMETRY: dict = {}

# The synthesis works on the table ring-major, (theta_d, theta_h, phi_d): a ring's cells are one
# contiguous block (90 x 180 cells, 130 kB a channel), and the sums go ring by ring over every
# view, so each ring's block stays in cache while all views read it (1.25x faster sums than in
# MERL's (theta_h, theta_d, phi_d) order, same values).
N_CELLS = RES_TH * RES_TD * RES_PD


def to_ring_major(flat):
    """(N_CELLS, C) per-cell values in MERL order -> the (90 theta_d, 90 theta_h, 180, C) cube."""
    v = np.asarray(flat).reshape(RES_TH, RES_TD, RES_PD, -1)
    return np.ascontiguousarray(v.transpose(1, 0, 2, 3))


def ring_major_index(cells):
    """MERL flat cell indices -> their ring-major flat indices."""
    ih, rest = np.divmod(np.asarray(cells, dtype=np.int64), RES_TD * RES_PD)
    id_, pd = np.divmod(rest, RES_PD)
    return (id_ * RES_TH + ih) * RES_PD + pd


def _cell_geometry(dtype=np.float64):
    """Per cell, ring-major: the tilt's log factor L (material independent, once per process)."""
    if "L" not in _GEOMETRY:
        th, td, pd = cell_centres()
        wi, wo = directions_from_half_diff(th, td, pd)
        ci, co = np.maximum(wi[:, 2], 1e-3), np.maximum(wo[:, 2], 1e-3)
        L = np.log(ci * co) - 2.0 * np.log(np.cos(td))
        _GEOMETRY["L"] = to_ring_major(L)[..., 0]
    key = ("L", np.dtype(dtype).str)
    if np.dtype(dtype) != np.float64 and key not in _GEOMETRY:
        _GEOMETRY[key] = _GEOMETRY["L"].astype(dtype)
    return _GEOMETRY.get(key, _GEOMETRY["L"])


@dataclass
class Controls:
    """The transform's controls per theta_d ring."""

    log_s: np.ndarray  # (90,)
    q: np.ndarray  # (90,) tilt in the scaled units q~ (q = q~ / V_ring)
    log_g: np.ndarray  # (90, C) per channel

    @classmethod
    def identity(cls, channels=3):
        return cls(np.zeros(RES_TD), np.zeros(RES_TD), np.zeros((RES_TD, channels)))


class Transform:
    """The cell-wise transform of one material's specular values, ring-major (90 theta_d, 90
    theta_h, 180, C): see ``to_ring_major``."""

    def __init__(self, spec, ring_var):
        self.spec = spec  # float32 for the solve's average channel, float64 for the table
        self.dtype = spec.dtype
        self.L = _cell_geometry(self.dtype)
        self.ring_var = np.maximum(np.asarray(ring_var, float), 1e-8)  # (90,) the measured variance per ring
        self.ih = np.arange(RES_TH, dtype=float) + 0.5

    def _weights(self, log_s):
        """Catmull-Rom weights per (theta_d, theta_h) ring pair for the lookup at theta_h / s:
        (4, 90, 90) source rings, weights and their d/d(log s).

        Catmull-Rom along the ring index, so that the lookup and its derivative are continuous in
        s (the Gauss-Newton steps use the derivative: a piecewise-linear lookup made the solved
        table jump as the sliders moved). Ring i's centre is u = i + 0.5 with u = sqrt(theta_h /
        (pi/2)) * 90; below the first centre the data are mirrored about theta_h = 0 (u = 0), where
        a lobe is even in the signed ring coordinate. At s = 1 the lookup returns the values."""
        s = np.exp(log_s)
        p = self.ih[None, :] / np.sqrt(s)[:, None] - 0.5  # (id, ih) fractional ring
        dp = -0.5 * (p + 0.5)  # d p / d log s
        inside = p <= RES_TH - 1.0
        pc = np.clip(p, -0.5, RES_TH - 1.0)
        i0 = np.floor(pc).astype(np.int64)
        f = pc - i0
        f2, f3 = f * f, f * f * f
        # Four weights per ring pair: the full-size arrays are touched once per weight instead of
        # once per polynomial term.
        w = 0.5 * np.stack([-f + 2.0 * f2 - f3, 2.0 - 5.0 * f2 + 3.0 * f3, f + 4.0 * f2 - 3.0 * f3, f3 - f2])
        dw = (
            0.5
            * np.stack([-1.0 + 4.0 * f - 3.0 * f2, -10.0 * f + 9.0 * f2, 1.0 + 8.0 * f - 9.0 * f2, 3.0 * f2 - 2.0 * f])
            * dp
        )
        w *= inside
        dw *= inside
        j = i0[None] + np.arange(-1, 3)[:, None, None]
        j = np.where(j < 0, -1 - j, np.minimum(j, RES_TH - 1))
        return j, w, dw

    def values(self, c: Controls, with_derivatives=False):
        """Specular values, ring-major (90, 90, 180, C). With derivatives: one array (90, 90, 180,
        3C) holding the values, d/d log s and d/d q~ side by side, the layout the ring sums read
        (written in place: stacking three 12 MB arrays cost 0.2 s of a synthesis). Computed in two
        halves of the rings on the sums' thread pool (numpy's gathers and arithmetic release the
        GIL)."""
        dt = self.dtype
        j, w, dw = self._weights(c.log_s)
        w, dw = w.astype(dt), dw.astype(dt)
        qr = (c.q / self.ring_var).astype(dt)
        inv_var = (1.0 / self.ring_var).astype(dt)
        gain = np.exp(c.log_g - 2.0 * c.log_s[:, None]).astype(dt)[:, None, None, :]  # (id, 1, 1, C)
        shape = self.spec.shape
        C = shape[-1]
        out = np.empty(shape[:-1] + (3 * C if with_derivatives else C,), dtype=dt)

        def ring_block(rows):
            a, b = rows
            if with_derivatives:
                o = np.zeros((b - a,) + shape[1:], dtype=dt)
            else:
                o = out[a:b]
                o.fill(0.0)
            tmp = np.empty(o.shape, dtype=dt)
            dl = np.zeros(o.shape, dtype=dt) if with_derivatives else None
            ring = np.arange(a, b)[:, None]
            for k in range(4):
                v = self.spec[ring, j[k, a:b]]  # (b - a, 90, 180, C)
                np.multiply(v, w[k, a:b, :, None, None], out=tmp)
                o += tmp
                if with_derivatives:
                    np.multiply(v, dw[k, a:b, :, None, None], out=tmp)
                    dl += tmp
            neg = o < 0.0
            np.copyto(o, 0.0, where=neg)
            tilt = np.exp(np.clip(qr[a:b, None, None] * self.L[a:b], -700.0, TILT_MAX))[..., None]
            o *= tilt
            o *= gain[a:b]
            if with_derivatives:
                out[a:b, ..., :C] = o
                np.copyto(dl, 0.0, where=neg)
                dl *= tilt
                dl *= gain[a:b]
                dl -= dt.type(2.0) * o
                out[a:b, ..., C : 2 * C] = dl
                np.multiply(o, (self.L[a:b] * inv_var[a:b, None, None])[..., None], out=out[a:b, ..., 2 * C :])

        half = RES_TD // 2
        parallel_map(ring_block, [(0, half), (half, RES_TD)])
        return out


class RingSums:
    """The profile operator regrouped by (theta_d ring, view): for per-cell values (ring-major),
    the sums of the five monomials per view, split by the ring of each cell. One sparse matrix per
    monomial (rows: ring x view, columns: ring-major cells), built once per operator."""

    def __init__(self, op: SliceOperator):
        from scipy.sparse import csr_matrix

        cells = np.asarray(op.cells, dtype=np.int64)
        self.n_views = len(op.theta_o)
        self.theta_o = np.asarray(op.theta_o, float)
        view = np.repeat(np.arange(self.n_views), np.diff(np.asarray(op.offsets)))
        col = ring_major_index(cells)
        # Rows ring-major too: consecutive rows read the same ring's block of cells.
        key = ((cells // RES_PD) % RES_TD) * self.n_views + view
        order = np.argsort(key * N_CELLS + col, kind="stable")  # by row, then by cell within a row
        n = self.n_views * RES_TD
        indptr = np.searchsorted(key[order], np.arange(n + 1)).astype(np.int64)
        idx = col[order].astype(np.int32)
        # Only the five columns used, gathered once each: converting and reordering all 15
        # columns of the (memory-mapped) operator took 2 of the 2.8 s this costs per process.
        weights = op.weights
        self.mats = [
            csr_matrix((np.asarray(weights[:, j], dtype=np.float64)[order], idx, indptr), shape=(n, N_CELLS))
            for j in _COLS
        ]

    def subset(self, views):
        """The same sums for some of the views only (rows sliced; the columns stay all cells)."""
        views = np.asarray(views, dtype=np.int64)
        rows = (np.arange(RES_TD)[:, None] * self.n_views + views[None, :]).ravel()
        out = object.__new__(RingSums)
        out.n_views, out.theta_o = len(views), self.theta_o[views]
        out.mats = [m[rows] for m in self.mats]
        return out

    def _per_view(self, out):
        """(rings * views, ...) rows -> (views, rings, ...)."""
        out = out.reshape((RES_TD, self.n_views) + out.shape[1:])
        return np.ascontiguousarray(np.swapaxes(out, 0, 1))

    def sums(self, values):
        """(views, 90 rings, 5 monomials[, k]) for ring-major per-cell values (N_CELLS,) or
        (N_CELLS, k). float32 values are summed in float32 (the solve's steering sums: half the
        memory traffic; 1e-6 relative), anything else in float64; the result is float64."""
        single = np.asarray(values).dtype == np.float32
        v = np.asarray(values, dtype=np.float32 if single else np.float64)
        # Each product in two halves of its rows: ten even tasks keep both threads busy (five
        # whole products left one thread idle for a fifth of the time).
        parts = parallel_map(lambda m: m @ v, self._halves(np.float32 if single else np.float64))
        out = np.stack([np.concatenate(parts[2 * j : 2 * j + 2]) for j in range(len(self.mats))], axis=1)
        return self._per_view(out.astype(np.float64, copy=False))

    def _halves(self, dtype=np.float64):
        """Each matrix's two row halves, sharing its index buffers (made once per dtype)."""
        from scipy.sparse import csr_matrix

        cache = self.__dict__.setdefault("_parts", {})
        key = np.dtype(dtype).str
        if key not in cache:
            n = self.mats[0].shape[0]
            parts = []
            for m in self.mats:
                data = m.data if np.dtype(dtype) == m.data.dtype else m.data.astype(dtype)
                for a, b in ((0, n // 2), (n // 2, n)):
                    lo, hi = m.indptr[a], m.indptr[b]
                    ptr = m.indptr[a : b + 1] - lo
                    parts.append(
                        csr_matrix((data[lo:hi], m.indices[lo:hi], ptr), shape=(b - a, m.shape[1]), copy=False)
                    )
            cache[key] = parts
        return cache[key]

    def energy(self, values):
        """(views, 90 rings[, k]): the zeroth monomial's sums alone."""
        v = np.asarray(values, dtype=np.float64)
        return self._per_view(self.mats[0] @ v)


def _stats(S):
    """(energy, mean x, mean phi, average variance) per view from (views, 5) sums about the mirror."""
    s0 = np.maximum(S[:, 0], 1e-300)
    mx, mp = S[:, 1] / s0, S[:, 2] / s0
    var = 0.5 * (S[:, 3] / s0 - mx * mx + S[:, 4] / s0 - mp * mp)
    return S[:, 0], mx, mp, var


def _residual_jacobian(Sr, dSr, goal_e, goal_mx, goal_v, weight):
    """Residuals (3V,) and their Jacobian (3V, 90) w.r.t. one per-ring control.

    ``Sr`` (V, 90, 5) are the sums split by ring (their sum over rings is the view's sums),
    ``dSr`` the same for the control's derivative values (ring r's control touches ring r only)."""
    S = Sr.sum(axis=1)
    e, mx, mp, var = _stats(S)
    s0 = np.maximum(S[:, 0], 1e-300)[:, None]
    d0, dx, dp_, dxx, dpp = (dSr[:, :, j] for j in range(5))
    de = d0 / s0
    dmx = (dx - mx[:, None] * d0) / s0
    dmp = (dp_ - mp[:, None] * d0) / s0
    dvar = 0.5 * (
        (dxx - (S[:, 3] / s0[:, 0])[:, None] * d0) / s0
        - 2 * mx[:, None] * dmx
        + (dpp - (S[:, 4] / s0[:, 0])[:, None] * d0) / s0
        - 2 * mp[:, None] * dmp
    )
    v = np.maximum(var, 1e-300)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.concatenate(
            [
                np.log(np.maximum(e, 1e-300) / goal_e) / UNITS[0],
                (mx - goal_mx) / UNITS[1],
                np.log(np.maximum(var, 1e-300) / goal_v) / UNITS[2],
            ]
        )
        J = np.concatenate([de / UNITS[0], dmx / UNITS[1], dvar / v / UNITS[2]])
    w = np.concatenate([weight[:, 0], weight[:, 1], weight[:, 2]])
    r = np.nan_to_num(r) * w
    J = np.nan_to_num(J) * w[:, None]
    return r, J


class Superseded(Exception):
    """A synthesis given up between its steps because its ``stop()`` said so (a newer slider
    move, or an Apply of the same sliders, made it moot)."""


def _second_difference(n):
    d = np.zeros((n - 2, n))
    for i in range(n - 2):
        d[i, i : i + 3] = (1.0, -2.0, 1.0)
    return d


_D2 = _second_difference(RES_TD)


@dataclass
class SolveReport:
    steps: int
    residual_start: float
    residual_end: float


def knot_basis(n_knots):
    """(90 rings, K) linear B-spline (hat) basis on K knots evenly spread over theta_d."""
    if n_knots >= RES_TD:
        return np.eye(RES_TD)
    x = np.arange(RES_TD) / (RES_TD - 1) * (n_knots - 1)
    k = np.arange(n_knots)
    return np.maximum(0.0, 1.0 - np.abs(x[:, None] - k[None, :]))


def solve_controls(
    transform: Transform,
    rings: RingSums,
    goal_alpha,
    goal_mx,
    goal_var,
    weight,
    steps=None,
    start_controls: Controls | None = None,
    n_knots=None,
    stop=None,
):
    """Damped Gauss-Newton on (log s, q~, log G_avg), each a hat spline over theta_d, on the
    average channel, added to ``start_controls`` (per ring).

    ``goal_*`` per view (the average channel's targets: energy, mean about the mirror x = theta +
    theta_o, average variance); ``weight`` (V, 3) per residual kind. ``stop()``, asked before
    each step, True: ``Superseded`` is raised. Returns (Controls, report)."""
    steps = STEPS if steps is None else steps
    B = knot_basis(KNOTS if n_knots is None else n_knots)
    K = B.shape[1]
    base = start_controls or Controls.identity(1)
    y = np.zeros(3 * K)  # knot offsets
    Bfull = np.kron(np.eye(3), B)  # (270, 3K)
    D2 = _second_difference(K) if K > 2 else np.zeros((0, K))
    reg = np.kron(np.eye(3), D2) / np.repeat(SMOOTH, len(D2))[:, None]
    x0 = np.concatenate([base.log_s, base.q, base.log_g[:, 0]])
    start = end = None
    n = RES_TD

    def controls(y):
        x = x0 + Bfull @ y
        return Controls(np.clip(x[:n], *LOG_S_RANGE), np.clip(x[n : 2 * n], *Q_RANGE), x[2 * n :, None].copy())

    c = controls(y)
    for _ in range(steps):
        if stop is not None and stop():
            raise Superseded
        both = rings.sums(transform.values(c, with_derivatives=True).reshape(N_CELLS, 3))
        Sr, Ss, Sq = both[..., 0], both[..., 1], both[..., 2]
        r, Jg = _residual_jacobian(Sr, Sr, goal_alpha, goal_mx, goal_var, weight)
        _, Js = _residual_jacobian(Sr, Ss, goal_alpha, goal_mx, goal_var, weight)
        _, Jq = _residual_jacobian(Sr, Sq, goal_alpha, goal_mx, goal_var, weight)
        J = np.concatenate([Js @ B, Jq @ B, Jg @ B], axis=1)  # (3V, 3K)
        # A robust (pseudo-Huber) loss: a view whose target is out of reach (a lobe clipped at
        # the horizon) must not pull every other view off theirs, yet a view far off still pulls
        # (its residual grows like sqrt|r|; a Cauchy loss let such views go). Smooth in r.
        robust = (1.0 + (r / ROBUST) ** 2) ** -0.25
        r = r * robust
        J = J * robust[:, None]
        rr = reg @ y
        cost = float(r @ r + rr @ rr)
        if start is None:
            start = cost
        A = J.T @ J + reg.T @ reg
        A[np.diag_indices_from(A)] += DAMPING * (np.diag(A) + 1.0)
        step = -np.linalg.solve(A, J.T @ r + reg.T @ rr)
        step *= min(1.0, MAX_STEP / max(float(np.abs(step).max()), 1e-300))  # a uniform scale: continuous
        y = y + step
        c = controls(y)
        end = cost
    return c, SolveReport(steps, start, end)


def channel_gains(transform: Transform, rings: RingSums, c: Controls, goal_alpha_rgb, weight):
    """Per channel G_c per ring by linear least squares on every view's energy (exact: the energy
    is linear in the gains), smoothed like the other controls. Returns (90, 3) log gains and the
    values at unit gains (``tabulate`` scales them: the transform is not run twice)."""
    shape = Controls(c.log_s, c.q, np.zeros((RES_TD, transform.spec.shape[-1])))
    vals = transform.values(shape)
    reg = _D2 / SMOOTH[2]
    out = np.zeros((RES_TD, 3))
    energy = rings.energy(vals.reshape(-1, vals.shape[-1]))  # (V, 90, C): energy per ring
    for ch in range(3):
        A = energy[:, :, ch]
        goal = np.asarray(goal_alpha_rgb[:, ch], float)
        ok = goal > 0
        w = weight / np.where(ok, goal, 1.0) / UNITS[0]  # relative errors, in units
        M = A * w[:, None]
        base = np.exp(c.log_g[:, 0])
        # Unknown: G = base * (1 + y); residual w (A (base (1 + y)) - goal).
        Mb = M * base[None, :]
        rhs = w * goal - Mb.sum(axis=1)
        H = Mb.T @ Mb + (reg * base[None, :]).T @ (reg * base[None, :])
        H[np.diag_indices_from(H)] += GAIN_DAMPING * (np.diag(H) + 1.0)  # a linear fit: barely damped
        y = np.linalg.solve(H, Mb.T @ rhs - (reg * base[None, :]).T @ (reg @ base))
        out[:, ch] = np.log(np.maximum(base * (1.0 + y), 1e-12))
    return out, vals


def spec_cubes(table: MerlTable, kd, split=True, avg_dtype=np.float32):
    """The specular part (``profiles.specular_part``) as the ring-major cubes the transforms read:
    r, g, b (90, 90, 180, 3) float64 for the table, and their mean (90, 90, 180, 1) in
    ``avg_dtype`` for the solve. Transposed once from the table's layout."""
    spec, avg = specular_part(table, kd, split)
    rgb = np.ascontiguousarray(spec.reshape(3, RES_TH, RES_TD, RES_PD).transpose(2, 1, 3, 0))
    return rgb, to_ring_major(avg.astype(avg_dtype)[:, None])


def tabulate(table: MerlTable, transform: Transform, c: Controls, kd, unit_gain_values=None) -> MerlTable:
    """The edited table: transformed specular values plus kd, input's missing cells kept missing.
    ``unit_gain_values``: the transform at these controls with zero log gains, if already made."""
    if unit_gain_values is None:
        vals = transform.values(c)  # ring-major (90 td, 90 th, 180, 3)
        gain = None
    else:
        vals, gain = unit_gain_values, np.exp(c.log_g)  # (90 td, C)
    C = vals.shape[-1]
    # Into MERL order (C, theta_h, theta_d, phi_d) in one pass, the gains applied on the way.
    rho = np.empty((C, RES_TH, RES_TD, RES_PD))
    src = np.transpose(vals, (3, 1, 0, 2))
    if gain is None:
        np.copyto(rho, src)
    else:
        np.multiply(src, gain.T[:, None, :, None], out=rho)
    rho = rho.reshape(C, -1)
    top = float(rho.max(initial=0.0))  # NaN propagates through max; the values are >= 0
    if not math.isfinite(top) or top > 1e30:
        raise ValueError("synthesis produced non-finite or absurd values; the slider targets are out of reach")
    rho += np.asarray(kd, float)[:, None]
    rho *= table.valid
    return MerlTable(rho, table.valid.copy(), None)
