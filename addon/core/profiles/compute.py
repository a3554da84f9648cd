"""Moment profiles of a MERL table: the diffuse/specular split and the per-view statistics."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..file.merl import MerlTable, horizon_mask
from .integrate import MAX_ORDER, centred_view_sums, default_views, get_operator, table_sums
from .moments import CHANNELS, KEYS_BY_ORDER, PROFILE_KEYS, monomials, profiles_from_sums, shift_amplification
from .quadrature import RuleParams, slice_rule

DIFFUSE_VIEW = math.radians(45.0)
# The float32 sums carry relative errors of about 5e-8 (measured); a shift that amplifies
# them more than this could move a standardized moment by more than ~3e-5, so such views
# are summed again about their mean. Lobes at the mirror stay far below it.
MAX_SHIFT_AMPLIFICATION = 100.0


@dataclass
class Profiles:
    """Moment profiles per channel ('r', 'g', 'b', 'avg'), each key -> array over theta_o.

    Undefined values (no energy in a slice) are NaN in memory and null in JSON.
    """

    theta_o: np.ndarray
    kd: np.ndarray
    channels: dict
    max_order: int = MAX_ORDER
    split: bool = True
    interp: str = "nearest"
    name: str = ""
    meta: dict = field(default_factory=dict)

    def __getitem__(self, channel):
        return self.channels[channel]

    def to_json(self) -> dict:
        def clean(a):
            return [None if not np.isfinite(v) else float(v) for v in np.asarray(a, dtype=float)]

        out = {"theta_o": clean(self.theta_o), "kd": clean(self.kd)}
        for ch in CHANNELS:
            out[ch] = {k: clean(self.channels[ch][k]) for k in KEYS_BY_ORDER[self.max_order]}
        return out

    @classmethod
    def from_json(cls, data: dict, name: str = "") -> "Profiles":
        """Profiles from the JSON ``to_json`` writes; ValueError naming the first fault (wrong
        types, lists of different lengths, values out of range) for anything else."""
        from ..limits import MAX_JSON_LIST

        def arr(v, where, length=None, finite=False):
            if not isinstance(v, list):
                raise ValueError(f"'{where}' must be a list of numbers, not {type(v).__name__}")
            if not 1 <= len(v) <= MAX_JSON_LIST or (length is not None and len(v) != length):
                want = f"{length}" if length is not None else f"1 to {MAX_JSON_LIST}"
                raise ValueError(f"'{where}' has {len(v)} values, expected {want}")
            out = np.empty(len(v))
            for i, x in enumerate(v):
                if x is None and not finite:
                    out[i] = np.nan
                elif isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and abs(x) < 1e300:
                    out[i] = float(x)
                else:
                    raise ValueError(f"'{where}[{i}]' is not a finite number: {str(x)[:40]!r}")
            return out

        if not isinstance(data, dict):
            raise ValueError(f"expected an object with theta_o, kd and channels, not {type(data).__name__}")
        for key in ("theta_o", "kd", *CHANNELS):
            if key not in data:
                raise ValueError(f"'{key}' is missing")
        theta = arr(data["theta_o"], "theta_o", finite=True)
        if (theta < 0).any() or (theta >= math.pi / 2).any():
            raise ValueError("'theta_o' values must lie in [0, pi/2) radians")
        kd = arr(data["kd"], "kd", 3, finite=True)
        channels = {}
        for ch in CHANNELS:
            if not isinstance(data[ch], dict):
                raise ValueError(f"'{ch}' must be an object of profile lists")
            channels[ch] = {k: arr(v, f"{ch}.{k}", len(theta)) for k, v in data[ch].items() if k in PROFILE_KEYS}
        orders = [o for o, keys in KEYS_BY_ORDER.items() if all(k in channels[ch] for ch in CHANNELS for k in keys)]
        if not orders:
            raise ValueError("'alpha' is missing from a channel")
        return cls(theta, kd, channels, max(orders), name=name)


FLOORS = ("min", "robust")
# The robust floor (an option; the paper's minimum stays the default): a low percentile, by
# slice area, over the part of the 45 deg slice where both directions are at most 70 deg from
# the normal. Measured tables (and networks trained on cosine-weighted values) are least
# reliable towards grazing, where single cells drop to ~0 and then set the paper's minimum;
# the percentile keeps one low cell elsewhere from doing the same. BENCHMARKS.md, "Measured
# materials", has both floors on 59 measured materials.
ROBUST_MAX_ANGLE = math.radians(70.0)
ROBUST_PERCENTILE = 0.05


def _slice_lower_cosine(cells):
    """cos of the lower direction's polar angle at each cell's centre (phi_h = 0)."""
    from ..file.merl import RES_PD, RES_TD, RES_TH

    ith, rest = np.divmod(np.asarray(cells), RES_TD * RES_PD)
    itd, ipd = np.divmod(rest, RES_PD)
    th = ((ith + 0.5) / RES_TH) ** 2 * (0.5 * np.pi)
    td = (itd + 0.5) / RES_TD * (0.5 * np.pi)
    pd = (ipd + 0.5) / RES_PD * np.pi
    # z of the two directions: cos td cos th -/+ sin td cos pd sin th.
    return np.cos(td) * np.cos(th) - np.abs(np.sin(td) * np.cos(pd) * np.sin(th))


def diffuse_floor(table: MerlTable, cache_dir=None, method: str = "min") -> np.ndarray:
    """kd per channel over the theta_o = 45 deg slice.

    ``min``: the minimum measured value (the paper, Sec. 2.2). ``robust``: the
    ROBUST_PERCENTILE quantile, weighted by slice area, of the cells whose two directions
    are within ROBUST_MAX_ANGLE of the normal (the minimum of all cells if none is).
    """
    if method not in FLOORS:
        raise ValueError(f"unknown diffuse floor {method!r} ({' or '.join(FLOORS)})")
    op = get_operator(np.array([DIFFUSE_VIEW]), cache_dir=cache_dir, memo=False)
    cells, weights = op.view(0)
    cells = np.asarray(cells)
    kd = np.zeros(3)
    if method == "robust":
        from .moments import exponents

        area = np.asarray(weights)[:, exponents(MAX_ORDER).index((0, 0))].astype(float)
        inner = _slice_lower_cosine(cells) >= math.cos(ROBUST_MAX_ANGLE)
    for c in range(3):
        ok = table.valid[c, cells]
        if not ok.any():
            continue
        values = table.rho[c, cells]
        if method == "robust" and (ok & inner).any():
            sel = ok & inner
            v, w = values[sel], area[sel]
            order = np.argsort(v, kind="stable")
            cum = np.cumsum(w[order])
            kd[c] = float(v[order][min(np.searchsorted(cum, ROBUST_PERCENTILE * cum[-1]), v.size - 1)])
        else:
            kd[c] = float(values[ok].min())
    return kd


def specular_part(table: MerlTable, kd, split=True, dtype=np.float64, with_average=True):
    """The per-cell specular part in the table's own (3, N_CELLS) layout, and its mean (N_CELLS,)
    (None without ``with_average``): rho - kd clipped at 0, missing cells 0. The mean is taken
    only where all three channels were measured, so it never mixes a missing cell in."""
    kd = np.asarray(kd, dtype=float) if split else np.zeros(3)
    spec = np.subtract(table.rho, kd[:, None].astype(dtype), dtype=dtype)  # contiguous, as stored
    np.maximum(spec, 0.0, out=spec)
    spec *= table.valid
    if not with_average:
        return spec, None
    avg = spec.sum(axis=0)
    avg /= 3
    avg *= table.valid.all(axis=0)
    return spec, avg


def specular_values(table: MerlTable, kd, split=True, dtype=np.float64, with_average=True) -> np.ndarray:
    """Per-cell specular part, (N_CELLS, 4): r, g, b and their mean (``specular_part``); missing
    cells are 0. ``with_average=False`` returns only the three channels."""
    spec, avg = specular_part(table, kd, split, dtype, with_average)
    out = np.empty((table.rho.shape[1], 4 if with_average else 3), dtype=dtype)
    out[:, :3] = spec.T
    if with_average:
        out[:, 3] = avg
    return out


def compute_profiles(
    table: MerlTable,
    theta_o=None,
    *,
    max_order: int = MAX_ORDER,
    split: bool = True,
    kd=None,
    interp: str = "nearest",
    cache_dir=None,
    progress=None,
    params: RuleParams = RuleParams(),
    floor: str = "min",
) -> Profiles:
    """All moment profiles of a table for the views ``theta_o`` (radians; default 0..89 deg).

    ``kd`` overrides the automatic diffuse floor; ``split=False`` analyses the whole BRDF.
    ``floor`` picks the automatic floor: ``min`` (the paper's) or ``robust`` (diffuse_floor).
    ``progress(done, total)`` is called while the (cached) operator is first built.
    """
    from ..limits import check

    max_order = check("max_order", max_order, "max_order")
    if floor not in FLOORS:
        raise ValueError(f"unknown diffuse floor {floor!r} ({' or '.join(FLOORS)})")
    theta_o = default_views() if theta_o is None else np.asarray(theta_o, dtype=float)
    check("elevations", theta_o.size, "theta_o (number of views)")
    if theta_o.ndim != 1 or not np.all(np.isfinite(theta_o)) or theta_o.min() < 0 or theta_o.max() >= np.pi / 2:
        raise ValueError("theta_o: view elevations must be finite, in [0, pi/2) radians")
    if split:
        kd = (
            diffuse_floor(table, cache_dir, floor)
            if kd is None
            else np.broadcast_to(np.asarray(kd, float), (3,)).copy()
        )
    else:
        kd = np.zeros(3)
    if interp not in ("nearest", "trilinear"):
        raise ValueError(f"unknown interpolation {interp!r} (nearest or trilinear)")
    exponent = None
    if interp == "trilinear" and all(np.array_equal(v, horizon_mask()) for v in table.valid):
        # The usual mask (every cell above the horizon measured): trilinear reading is one
        # more cached operator. Trilinear values are continuous across cell edges, so the
        # point-sampled rule (no splitting at the edges) converges as well.
        params = replace(params, exact=False, interp="trilinear")
        interp = "operator"
    if interp in ("nearest", "operator"):
        # float32 halves the memory traffic of the gather; against float64 it moves alpha
        # and sigma^2 by ~1e-6 relative (measured in BENCHMARKS.md), far inside the targets.
        op = get_operator(theta_o, params, cache_dir=cache_dir, progress=progress)
        peak = table.rho.max(axis=1)
        if np.any((peak > 0) & ((peak < 2.0**-16) | (peak > 2.0**16))):
            values, exponent = _normalized_values(table, kd, split)
            sums = table_sums(op, values, max_order)
        else:
            same_mask = np.array_equal(table.valid[0], table.valid[1]) and np.array_equal(
                table.valid[0], table.valid[2]
            )
            values = specular_values(table, kd, split, np.float32, with_average=not same_mask)
            sums = table_sums(op, values, max_order)
            if same_mask:
                # Sums are linear in the values: with one mask for all channels, the average
                # channel's sums are the mean of the three (a quarter less to gather).
                sums = np.concatenate([sums, sums.mean(axis=1, keepdims=True)], axis=1)
        sums, centre_t, centre_p = _recentre_far_lobes(op, values, sums, theta_o, max_order)
    else:  # trilinear over another mask: the renormalisation depends on it, point by point
        sums = _trilinear_sums(table, kd, theta_o, max_order, params, progress)
        centre_t, centre_p = np.broadcast_to(-theta_o[:, None], sums.shape[:2]), 0.0
        interp = "trilinear"
    if interp == "operator":
        interp = "trilinear"
    stats = profiles_from_sums(sums, centre_t, max_order, centre_phi=centre_p)
    if exponent is not None:
        stats["alpha"] = np.ldexp(stats["alpha"], exponent[None, :])  # only the energy carries the scale
    channels = {ch: {k: stats[k][:, i] for k in KEYS_BY_ORDER[max_order]} for i, ch in enumerate(CHANNELS)}
    return Profiles(theta_o, kd, channels, max_order, split, interp, table.name)


def _normalized_values(table, kd, split):
    """Specular values (N_CELLS, 4: r, g, b, average), each column scaled by a power of two
    so that its peak is in [0.5, 1); returns (float32 values, exponents).

    For tables far outside float32's comfortable range (a near-black channel, subnormal or
    huge values): the moments do not depend on the scale, the energy is scaled back exactly,
    and nothing underflows in the float32 products with the small weights of narrow cells.
    """
    kd = np.asarray(kd, dtype=float) if split else np.zeros(3)
    spec = np.maximum(table.rho - kd[:, None], 0.0) * table.valid
    cols = np.vstack([spec, spec.mean(axis=0, keepdims=True) * table.valid.all(axis=0)])
    del spec
    peak = cols.max(axis=1)
    exponent = np.where(peak > 0, np.frexp(peak)[1], 0)
    # ldexp scales without forming 2**-e, which would overflow for a subnormal peak.
    return np.ldexp(cols, -exponent[:, None]).T.astype(np.float32), exponent


def _recentre_far_lobes(op, values, sums, theta_o, max_order):
    """Sum again, about their own mean, the (view, channel) pairs the shift would spoil.

    Returns (sums, centre_theta, centre_phi), the centres per (view, channel)."""
    centre_t = np.repeat(-theta_o[:, None], sums.shape[1], axis=1)
    centre_p = np.zeros(sums.shape[:2])
    if max_order < 2:
        return sums, centre_t, centre_p
    bad = shift_amplification(sums, max_order) > MAX_SHIFT_AMPLIFICATION
    if not bad.any():
        return sums, centre_t, centre_p
    sums = sums.copy()
    if values.shape[1] == 3:  # one mask for all channels: the average is their mean
        values = np.concatenate([values, values.mean(axis=1, keepdims=True)], axis=1)
    for k in np.flatnonzero(bad.any(axis=1)):
        chans = bad[k]
        mass = np.where(sums[k, :, 0] > 0, sums[k, :, 0], 1.0)
        mx = sums[k, :, 1] / mass  # first-order sums cancel nothing: good centres
        mp = sums[k, :, 2] / mass
        sums[k, chans] = centred_view_sums(op, k, values, mx, mp, max_order)[chans]
        centre_t[k, chans] = -theta_o[k] + mx[chans]
        centre_p[k, chans] = mp[chans]
    return sums, centre_t, centre_p


def _trilinear_sums(table, kd, theta_o, max_order, params, progress):
    """The trilinear sums point by point, for a mask of measured cells that is not the usual
    one (the renormalisation over measured neighbours then depends on the table). It reads
    the specular part (max(rho - kd, 0) per cell, as the nearest path and the cached
    trilinear operator do), so all three agree where their masks do."""
    from ..file.merl import MerlTable, lookup_angles

    params = replace(params, exact=False)
    spec_table = MerlTable(np.maximum(table.rho - kd[:, None], 0.0) * table.valid, table.valid, None)
    out = []
    for k, to in enumerate(theta_o):
        rule = slice_rule(float(to), params)
        spec, valid = lookup_angles(spec_table, rule.theta_h, rule.theta_d, rule.phi_d, "trilinear")
        vals = np.vstack([spec, np.where(valid.all(axis=0), spec.mean(axis=0), 0.0)])
        out.append((vals * rule.weight) @ monomials(rule.theta + to, rule.phi, max_order))
        if progress:
            progress(k + 1, len(theta_o))
    return np.asarray(out)


def _stats(sums, centre, max_order, centre_phi=0.0):
    st = profiles_from_sums(
        sums,
        np.asarray(centre)[:, None],
        max_order,
        centre_phi=np.asarray(centre_phi)[..., None] if np.ndim(centre_phi) else centre_phi,
    )
    return {k: v for k, v in st.items()}


def function_profiles(f, theta_o, max_order: int = MAX_ORDER, **rule):
    """Profiles of an analytic slice ``f(theta, phi, theta_o) -> (C, n)``: dict key -> (views, C).

    This is the integrator's function interface, used against closed forms."""
    from ..limits import check
    from .integrate import function_sums

    max_order = check("max_order", max_order, "max_order")
    theta_o = np.atleast_1d(np.asarray(theta_o, dtype=float))
    sums, ct, cp = function_sums(f, theta_o, max_order, **rule)
    return _stats(sums, ct, max_order, cp)


def monte_carlo_profiles(evaluate, theta_o, n_samples: int, seed: int = 0, max_order: int = MAX_ORDER):
    """The paper's estimator (Eq. 6), for comparison: dict key -> (views, C)."""
    from ..limits import check
    from .integrate import monte_carlo_sums

    n_samples = check("mc_samples", n_samples, "n_samples")
    seed, max_order = check("seed", seed, "seed"), check("max_order", max_order, "max_order")
    theta_o = np.atleast_1d(np.asarray(theta_o, dtype=float))
    return _stats(monte_carlo_sums(evaluate, theta_o, n_samples, seed, max_order), -theta_o, max_order)
