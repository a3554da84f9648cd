"""Moment profiles of a MERL table: the diffuse/specular split and the per-view statistics."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .integrate import MAX_ORDER, centred_view_sums, default_views, get_operator, table_sums
from .merl import MerlTable
from .moments import CHANNELS, KEYS_BY_ORDER, monomials, profiles_from_sums, shift_amplification
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
        def arr(v):
            return np.array([np.nan if x is None else float(x) for x in v])

        channels = {ch: {k: arr(v) for k, v in data[ch].items()} for ch in CHANNELS}
        order = max(o for o, keys in KEYS_BY_ORDER.items() if all(k in channels["avg"] for k in keys))
        return cls(arr(data["theta_o"]), arr(data["kd"]), channels, order, name=name)


def diffuse_floor(table: MerlTable, cache_dir=None) -> np.ndarray:
    """kd per channel: the minimum measured value over the theta_o = 45 deg slice (Sec. 2.2)."""
    op = get_operator(np.array([DIFFUSE_VIEW]), cache_dir=cache_dir, memo=False)
    cells = np.asarray(op.view(0)[0])
    kd = np.zeros(3)
    for c in range(3):
        ok = table.valid[c, cells]
        if ok.any():
            kd[c] = float(table.rho[c, cells][ok].min())
    return kd


def specular_values(table: MerlTable, kd, split=True, dtype=np.float64, with_average=True) -> np.ndarray:
    """Per-cell specular part, (N_CELLS, 4): r, g, b and their mean; missing cells are 0.

    The average is taken only where all three channels were measured, so it never mixes a
    missing cell in. ``with_average=False`` returns only the three channels.
    """
    kd = np.asarray(kd, dtype=float) if split else np.zeros(3)
    # Worked in the table's own (3, cells) layout, which is contiguous, and transposed once.
    spec = np.subtract(table.rho, kd[:, None].astype(dtype), dtype=dtype)
    np.maximum(spec, 0.0, out=spec)
    spec *= table.valid
    out = np.empty((table.rho.shape[1], 4 if with_average else 3), dtype=dtype)
    out[:, :3] = spec.T
    if with_average:
        avg = spec.sum(axis=0)
        avg /= 3
        avg *= table.valid.all(axis=0)
        out[:, 3] = avg
    return out


def compute_profiles(table: MerlTable, theta_o=None, *, max_order: int = MAX_ORDER, split: bool = True,
                     kd=None, interp: str = "nearest", cache_dir=None, progress=None,
                     params: RuleParams = RuleParams()) -> Profiles:
    """All moment profiles of a table for the views ``theta_o`` (radians; default 0..89 deg).

    ``kd`` overrides the automatic diffuse floor; ``split=False`` analyses the whole BRDF.
    ``progress(done, total)`` is called while the (cached) operator is first built.
    """
    if not 0 <= max_order <= MAX_ORDER:
        raise ValueError(f"max order must be 0..{MAX_ORDER}")
    theta_o = default_views() if theta_o is None else np.asarray(theta_o, dtype=float)
    if split:
        kd = diffuse_floor(table, cache_dir) if kd is None else np.broadcast_to(np.asarray(kd, float), (3,)).copy()
    else:
        kd = np.zeros(3)
    if interp == "nearest":
        # float32 halves the memory traffic of the gather; against float64 it moves alpha
        # and sigma^2 by ~1e-6 relative (measured in BENCHMARKS.md), far inside the targets.
        op = get_operator(theta_o, params, cache_dir=cache_dir, progress=progress)
        exponent = None
        peak = table.rho.max(axis=1)
        if np.any((peak > 0) & ((peak < 2.0 ** -16) | (peak > 2.0 ** 16))):
            values, exponent = _normalized_values(table, kd, split)
            sums = table_sums(op, values, max_order)
        else:
            same_mask = (np.array_equal(table.valid[0], table.valid[1])
                         and np.array_equal(table.valid[0], table.valid[2]))
            values = specular_values(table, kd, split, np.float32, with_average=not same_mask)
            sums = table_sums(op, values, max_order)
            if same_mask:
                # Sums are linear in the values: with one mask for all channels, the average
                # channel's sums are the mean of the three (a quarter less to gather).
                sums = np.concatenate([sums, sums.mean(axis=1, keepdims=True)], axis=1)
        sums, centre_t, centre_p = _recentre_far_lobes(op, values, sums, theta_o, max_order)
    elif interp == "trilinear":
        sums = _trilinear_sums(table, kd, theta_o, max_order, params, progress)
        centre_t, centre_p = np.broadcast_to(-theta_o[:, None], sums.shape[:2]), 0.0
    else:
        raise ValueError(f"unknown interpolation {interp!r} (nearest or trilinear)")
    stats = profiles_from_sums(sums, centre_t, max_order, centre_phi=centre_p)
    if interp == "nearest" and exponent is not None:
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
    from .merl import lookup_angles

    from dataclasses import replace

    # Trilinear values are continuous across cell edges, so the point-sampled rule (no
    # splitting at the edges, which is for the nearest-cell steps) converges as well, faster.
    params = replace(params, exact=False)
    out = []
    for k, to in enumerate(theta_o):
        rule = slice_rule(float(to), params)
        rho, valid = lookup_angles(table, rule.theta_h, rule.theta_d, rule.phi_d, "trilinear")
        spec = np.maximum(rho - kd[:, None], 0.0) * valid
        vals = np.vstack([spec, np.where(valid.all(axis=0), spec.mean(axis=0), 0.0)])
        out.append((vals * rule.weight) @ monomials(rule.theta + to, rule.phi, max_order))
        if progress:
            progress(k + 1, len(theta_o))
    return np.asarray(out)


def _stats(sums, centre, max_order, centre_phi=0.0):
    st = profiles_from_sums(sums, np.asarray(centre)[:, None], max_order, centre_phi=np.asarray(centre_phi)[..., None]
                            if np.ndim(centre_phi) else centre_phi)
    return {k: v for k, v in st.items()}


def function_profiles(f, theta_o, max_order: int = MAX_ORDER, **rule):
    """Profiles of an analytic slice ``f(theta, phi, theta_o) -> (C, n)``: dict key -> (views, C).

    This is the integrator's function interface, used against closed forms."""
    from .integrate import function_sums

    theta_o = np.atleast_1d(np.asarray(theta_o, dtype=float))
    sums, ct, cp = function_sums(f, theta_o, max_order, **rule)
    return _stats(sums, ct, max_order, cp)


def monte_carlo_profiles(evaluate, theta_o, n_samples: int, seed: int = 0, max_order: int = MAX_ORDER):
    """The paper's estimator (Eq. 6), for comparison: dict key -> (views, C)."""
    from .integrate import monte_carlo_sums

    theta_o = np.atleast_1d(np.asarray(theta_o, dtype=float))
    return _stats(monte_carlo_sums(evaluate, theta_o, n_samples, seed, max_order), -theta_o, max_order)
