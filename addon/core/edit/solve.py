"""The per-view solve: sliders -> per-view targets -> reciprocal transform -> table.

``edit`` is the public entry point (the CLI, the Blender operator and the demo call it).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..file.merl import RES_TD, MerlTable
from ..fits.curves import LAMBERT_VARIANCE, fit_material
from ..limits import TARGET_FIELDS, check_targets
from ..profiles.compute import Profiles, compute_profiles
from ..profiles.integrate import directional_albedo, get_operator
from . import reciprocal as R
from .blas import one_thread
from .fidelity import Fidelity, measure
from .reach import ReachableRegion, reachable_region
from .scale import roughness_source, source_key
from .targets import EditTargets, ViewTargets, announced, resolve_targets, view_targets


@dataclass
class EditResult:
    table: MerlTable
    target_mu_slope: float
    target_sigma2: float
    achieved_mu_slope: float | None
    achieved_sigma2: float | None
    max_albedo: np.ndarray  # per channel, over the sampled views
    warnings: list = field(default_factory=list)
    profiles: Profiles | None = None  # re-measured profiles of the output
    fidelity: Fidelity | None = None  # per-view figures against the sliders' targets
    region: ReachableRegion | None = None
    clamped: bool = False  # the request lay outside the region and was moved to its edge
    requested: tuple | None = None  # (mu, sigma2) before clamping
    timings: dict = field(default_factory=dict)  # seconds: synthesis, remeasure
    reused: bool = False  # the synthesis was a kept one (``edit(..., keep=True)``), not solved again
    targets: ViewTargets | None = None  # the per-view promise the table was made for
    announced: tuple = (None, None)  # (mu~, sigma~^2) the targets re-fit to: what the panel showed
    nothing_to_do: bool = False  # the request was clamped back to the fit: no edit was made
    operator: dict | None = None  # the roughness edit's parameters (scale, floor, masking, tilt)

    @property
    def energy_gain(self) -> bool:
        return bool(np.any(self.max_albedo > 1.0))


_RINGS: dict = {}


# A draft (the live preview's first image while a slider moves, refined afterwards by the full
# synthesis): fewer Gauss-Newton steps on every DRAFT_VIEW_STRIDE-th view. The controls are
# 16-knot splines over theta_d, so a third of the views pins them roughly; the full solve keeps
# every view (every other one already loosened ggx_mirror's worst view variance from 22 % to 42 %).
DRAFT_STEPS = 3
DRAFT_VIEW_STRIDE = 3
SOLVE_DTYPE = np.float32  # the Gauss-Newton's steering sums (the table is float64)


_LOCKS: dict = {}


def _lock():
    """One lock per process (Blender's warm-up and live-preview threads may both ask for the
    ring sums): a process forked while another thread held the parent's would inherit it held."""
    import os
    import threading

    pid = os.getpid()
    lock = _LOCKS.get(pid)
    return lock if lock is not None else _LOCKS.setdefault(pid, threading.Lock())  # setdefault: atomic


def _rings(theta_o, stride=1):
    with _lock():
        op = get_operator(theta_o)
        key = id(op)
        if _RINGS.get("key") != key:
            _RINGS.clear()
            _RINGS.update(key=key, value={1: R.RingSums(op)}, op=op)
        subsets = _RINGS["value"]
        if stride not in subsets:
            subsets[stride] = subsets[1].subset(np.arange(0, len(theta_o), stride))
        return subsets[stride]


def warm(theta_o):
    """Build what every edit of these views shares (the profile operator, its ring sums, the
    tilt's geometry), once per process. Blender calls it in a thread after an analysis, so
    that the job processes it forks for Apply inherit them instead of rebuilding (~1 s)."""
    theta_o = np.asarray(theta_o, float)
    for stride in (1, DRAFT_VIEW_STRIDE):
        _rings(theta_o, stride)._halves(SOLVE_DTYPE)  # the steering sums' float32 copies too
    R._cell_geometry(SOLVE_DTYPE)


def _avg_goals(prof: Profiles, vt: ViewTargets):
    """The average channel's per-view goals: energy, mean about the mirror, average variance."""
    theta = np.asarray(prof.theta_o, float)
    alpha = vt.alpha.mean(axis=1)
    mean, var = vt.avg_mean, vt.avg_var
    return alpha, np.nan_to_num(mean + theta), np.maximum(np.nan_to_num(var, nan=LAMBERT_VARIANCE), 1e-12)


def _weights(theta, alpha):
    """Per view and residual kind: views with little energy count less (their moments are noise
    to the user), grazing views beyond 80 deg a little less."""
    peak = float(np.max(np.where(theta <= math.radians(80.0) + 1e-9, alpha, 0.0), initial=0.0))
    f = np.clip(alpha / max(peak, 1e-300) / 0.05, 0.0, 1.0) ** 0.5
    f = np.where(theta > math.radians(80.0) + 1e-9, 0.3 * f, f)
    return np.repeat(f[:, None], 3, axis=1)


def synthesize(table: MerlTable, prof: Profiles, fit: dict, vt: ViewTargets, draft=False, stop=None):
    """The reciprocal table for per-view targets ``vt``; returns (table, controls, report).
    ``draft``: a quick, rougher solve (DRAFT_STEPS on every DRAFT_VIEW_STRIDE-th view).
    ``stop()``, asked before every step: True raises ``Superseded`` (the work is dropped)."""
    kd = np.asarray(prof.kd, float) if prof.split else np.zeros(3)
    spec_rgb, spec_avg = R.spec_cubes(table, kd, prof.split, SOLVE_DTYPE)
    theta = np.asarray(prof.theta_o, float)
    rings = _rings(theta)
    ring_centres = (np.arange(RES_TD) + 0.5) / RES_TD * (0.5 * math.pi)
    p = prof["avg"]
    measured_var = np.nan_to_num(
        0.5 * (np.asarray(p["sigma_tt"], float) + np.asarray(p["sigma_pp"], float)), nan=LAMBERT_VARIANCE
    )
    ring_var = np.interp(ring_centres, theta, measured_var)
    goal_e, goal_mx, goal_v = _avg_goals(prof, vt)
    weight = _weights(theta, goal_e)
    # (Out-of-reach views are not down-weighted by the reach test: a yes/no weight would make the
    # map from sliders to tables jump as a view crosses the boundary. The robust loss tames them.)
    goal_e = np.maximum(goal_e, 1e-12 * max(float(goal_e.max(initial=0.0)), 1e-300))
    # The solve steers on the average channel in float32 (half the memory traffic of its 8 steps);
    # the table itself is made in float64 from the solved controls, and re-measured in float64.
    avg = R.Transform(spec_avg, ring_var)
    # Start from the per-view answer read off at theta_d = theta_o (where each view's lobe is):
    # the width by the variance ratio, the gain by the energy ratio (1/s^2 already keeps it).
    measured_e = np.nan_to_num(np.asarray(p["alpha"], float))
    with np.errstate(divide="ignore", invalid="ignore"):
        ls0 = np.nan_to_num(0.5 * np.log(goal_v / np.maximum(measured_var, 1e-300)))
        lg0 = np.nan_to_num(np.log(goal_e / np.maximum(measured_e, 1e-300)))
    start = R.Controls(
        np.clip(np.interp(ring_centres, theta, ls0), *R.LOG_S_RANGE),
        np.zeros(RES_TD),
        np.clip(np.interp(ring_centres, theta, lg0), -5.0, 5.0)[:, None],
    )
    stride = DRAFT_VIEW_STRIDE if draft else 1
    sub = slice(None, None, stride)
    controls, report = R.solve_controls(
        avg,
        _rings(theta, stride),
        goal_e[sub],
        goal_mx[sub],
        goal_v[sub],
        weight[sub],
        start_controls=start,
        steps=DRAFT_STEPS if draft else None,
        stop=stop,
    )
    del avg, spec_avg
    if stop is not None and stop():
        raise R.Superseded
    rgb = R.Transform(spec_rgb, ring_var)
    controls.log_g, unit = R.channel_gains(rgb, rings, controls, vt.alpha, weight[:, 0])
    return R.tabulate(table, rgb, controls, kd, unit), controls, report


# One full synthesis kept per process (``edit(..., keep=True)``): the live preview's, made in a
# Blender thread when a slider settles, is what an Apply of the same sliders writes; the Apply's
# forked child inherits it and only re-measures. Keyed by the content of everything
# ``synthesize`` reads, so a table read afresh from the same file finds it; one entry bounds it.
_KEPT: dict = {}


def _synthesis_key(table: MerlTable, prof: Profiles, fit: dict, vt: ViewTargets) -> str:
    import hashlib

    h = hashlib.blake2b(digest_size=20)
    for a in (table.rho, table.valid, prof.theta_o, prof.kd, vt.theta_o, vt.alpha, vt.avg_mean, vt.avg_var):
        a = np.ascontiguousarray(a)
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(a.data)
    for k in ("alpha", "mu_theta", "sigma_tt", "sigma_pp"):
        h.update(np.ascontiguousarray(prof["avg"][k], "<f8").data)
    h.update(repr((prof.split, fit.get("mu_slope"), fit.get("sigma2"), vt.mode, vt.mu_slope, vt.sigma2)).encode())
    return h.hexdigest()


ALBEDO_STRIDE = 3  # the albedo check on every third analysed view (and the last): 30 of 90, 0.1 s
ENERGY_WARNING = 0.2  # warn when a view's re-measured energy is this far off its target


def _views_off(theta, got, want, use, what):
    """A warning naming the views (rows of ``use``) whose energy ``got`` is more than
    ENERGY_WARNING off ``want``, or None; ``what`` says how, e.g. 'energy not held'."""
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(use, np.abs(got / want - 1.0), 0.0)
    bad = off > ENERGY_WARNING
    if bad.ndim > 1:
        bad = bad.any(axis=1)
    if not bad.any():
        return None
    deg = np.degrees(np.asarray(theta, float)[bad])
    return f"{what} at {int(bad.sum())} view(s) ({deg.min():.0f}-{deg.max():.0f} deg): up to {100 * off.max():.0f} %"


def _energy_note(new_prof, vt):
    """A warning naming the views (up to 80 deg, >= 1e-6 of the peak) whose energy is > 20 % off."""
    theta = np.asarray(vt.theta_o, float)
    got = np.stack([np.nan_to_num(np.asarray(new_prof[c]["alpha"], float)) for c in "rgb"], axis=1)
    want = vt.alpha
    use = (theta[:, None] <= math.radians(80.0) + 1e-9) & (want > 1e-6 * max(float(want.max(initial=0.0)), 1e-300))
    return _views_off(theta, got, want, use, "energy not held")


# A re-fitted slider this far from its target is reported (the issue-4 round-trip tolerances):
# the per-view solve can hold every view's energy and variance yet leave the fitted slope short.
MU_TOLERANCE = 0.01
SIGMA2_TOLERANCE = 0.02


def _target_note(achieved_mu, achieved_s2, mu_t, s2_t):
    """One warning naming each fitted slider value the written table misses, or None."""
    misses = []
    if achieved_mu is not None and mu_t is not None and abs(achieved_mu - mu_t) > MU_TOLERANCE:
        misses.append(f"mean slope {achieved_mu:+.3f} for {mu_t:+.3f}")
    if achieved_s2 is not None and s2_t is not None and abs(achieved_s2 - s2_t) > SIGMA2_TOLERANCE * s2_t:
        misses.append(f"variance {achieved_s2:.4g} for {s2_t:.4g}")
    if not misses:
        return None
    return "target not reached: the written table re-fits " + " and ".join(misses)


def _finish(out, mu_t, s2_t, warnings, prof, remeasure, vt=None, draft=False, **extra):
    # A draft is only looked at (the full synthesis follows): no albedo pass (0.1-0.3 s).
    albedo = np.full(3, np.nan) if draft else directional_albedo(out, prof.theta_o, ALBEDO_STRIDE).max(axis=0)
    if np.any(albedo > 1.0):
        warnings.append(
            f"the edited material reflects more than it receives (largest directional albedo "
            f"{albedo.max():.3f} > 1): lower its Strength"
        )
    achieved_mu = achieved_s2 = None
    new_prof = fid = None
    timings = extra.pop("timings", {})
    source = extra.pop("source", None)  # the table edited: for the energy moved far from the lobes
    if remeasure:
        t0 = time.perf_counter()
        new_prof = compute_profiles(out, prof.theta_o, kd=prof.kd if prof.split else None, split=prof.split)
        f = fit_material(new_prof)
        achieved_mu, achieved_s2 = f["mu_slope"], f["sigma2"]
        said_mu, said_s2 = extra.get("announced") or (mu_t, s2_t)
        miss = _target_note(achieved_mu, achieved_s2, said_mu, said_s2)
        if miss:
            warnings.append(miss)
        if vt is not None:
            fid = measure(new_prof, vt, prof, tables=None if source is None else (out, source))
            note = _energy_note(new_prof, vt)
            if note:
                warnings.append(note)
        timings["remeasure"] = time.perf_counter() - t0
    return EditResult(
        out, mu_t, s2_t, achieved_mu, achieved_s2, albedo, warnings, new_prof, fid, timings=timings, **extra
    )


@dataclass
class Announcement:
    """What an edit will deliver, known before any synthesis (the panel shows it beside the
    sliders; ``edit`` makes the table from the same point, so the two cannot disagree)."""

    requested: tuple  # (mu~, sigma~^2) as set (resolved into the slider ranges)
    point: tuple  # the point the targets are made for: the request, or the region's nearest point
    clamped: bool
    announced: tuple  # (mu~, sigma~^2) the targets re-fit to
    out_of_reach: float  # share of the judged views whose target is out of reach
    targets: ViewTargets
    warnings: list
    fitted: tuple  # the material's own (mu~, sigma~^2)
    region: ReachableRegion | None = None
    energy_kept: bool = True  # strength, colour and boost untouched, warp mode

    @property
    def at_fit(self) -> bool:
        """Clamped back onto the material's own fit (warp mode): the lobes stay as measured."""
        return self.clamped and self.point == self.fitted and self.targets.mode == "warp"

    @property
    def nothing_to_do(self) -> bool:
        """Clamped back onto the fit with the energy untouched: the edit would change nothing
        (SPEC §3: reported so, never a met edit)."""
        return self.at_fit and self.energy_kept


def _announce_roughness(prof, fit, targets, region):
    """The panel's instant word on a roughness edit, from the material's curve: the variance
    asked for and the mean slope the table will re-fit to (on the curve, or tilted off it within
    the region), the clamp Apply will make (``roughness_point``). The per-view figures come from
    the synthesis itself (the live draft, then Apply)."""
    asked, point, warnings = roughness_point(targets, fit, region)
    vt = view_targets(prof, fit, EditTargets(), float(fit["mu_slope"]), float(fit["sigma2"]))
    fitted = (float(fit["mu_slope"]), float(fit["sigma2"]))
    return Announcement(asked, point, asked != point, point, 0.0, vt, warnings, fitted, region, False)


def announce(prof: Profiles, fit: dict, targets: EditTargets, region: ReachableRegion | None = None) -> Announcement:
    """Resolve the sliders, clamp them into the region (edits that move mu~ or sigma~^2), make the
    per-view targets and say what they re-fit to and how many judged views are out of reach."""
    from .fidelity import out_of_reach

    if fit.get("mu_slope") is None or fit.get("sigma2") is None:
        raise ValueError("the material has no specular lobe to edit (all its energy is in kd)")
    if is_roughness_edit(targets) and region is not None and region.curve:
        return _announce_roughness(prof, fit, targets, region)
    mu, s2, warnings = resolve_targets(targets, fit)
    # A request the slider ranges held back is clamped too (it may land on the fit: nothing to do).
    asked_mu = mu if targets.mu_slope is None else float(targets.mu_slope)
    asked_s2 = s2 if targets.sigma2 is None or targets.lock else float(targets.sigma2)
    requested, clamped = (asked_mu, asked_s2), (asked_mu, asked_s2) != (mu, s2)
    if not targets.is_identity() and not targets.is_energy_only():
        if region is None:
            region = reachable_region(prof, fit, mode=targets.mode)
        mu_c, s2_c, moved = region.clamp(mu, s2)
        clamped |= moved
        if moved:
            warnings.append(
                f"mean slope {mu:+.3f} and variance {s2:.4g} lie outside what a reciprocal table of "
                f"this material can show: clamped to the nearest reachable point ({mu_c:+.3f}, {s2_c:.4g})"
            )
            mu, s2 = mu_c, s2_c
    vt = view_targets(prof, fit, targets, mu, s2)
    judged, reach = out_of_reach(vt, prof)
    share = float((judged & ~reach).sum() / max(int(judged.sum()), 1))
    fitted = (float(fit["mu_slope"]), float(fit["sigma2"]))
    kept = targets.mode == "warp" and targets.strength == 1.0 and tuple(targets.colour) == (1.0, 1.0, 1.0)
    kept = kept and targets.grazing_boost == 1.0
    return Announcement(requested, (mu, s2), clamped, announced(vt), share, vt, warnings, fitted, region, kept)


def edit(
    table: MerlTable,
    targets: EditTargets,
    prof: Profiles | None = None,
    fit: dict | None = None,
    remeasure: bool = True,
    progress=None,
    region: ReachableRegion | None = None,
    draft: bool = False,
    keep: bool = False,
    stop=None,
) -> EditResult:
    """Re-synthesize ``table`` for the slider ``targets``. Never modifies ``table``.

    The request is clamped into the material's reachable region (reported), the per-view
    targets follow from the sliders (``targets.view_targets``), and one reciprocal transform
    of the specular table is solved to meet them (``reciprocal``). ``progress(done, total)``
    is called once per stage. ``draft``: the quick, rougher synthesis a slider drag shows first.
    Model mode runs the same synthesis toward the model's targets (``targets.view_targets``).
    ``keep``: remember this full synthesis (one per process), and take a remembered one made
    from the same inputs instead of solving again (the live preview's, for Apply). ``stop()``:
    asked between the synthesis's steps; True gives the edit up (``Superseded``), so that work
    nobody will see does not hold a core."""
    check_targets(targets, TARGET_FIELDS)  # before any work: what the command line and the panel refuse
    if prof is None:
        prof = compute_profiles(table)
    if fit is None:
        fit = fit_material(prof)
    if fit.get("mu_slope") is None or fit.get("sigma2") is None:
        raise ValueError(f"{table.name}: the material has no specular lobe to edit (all its energy is in kd)")
    tell = progress or (lambda done, total: None)
    if is_roughness_edit(targets):
        if draft:
            return roughness_draft(table, targets, prof, fit, region)
        return roughness_edit(
            table, targets, prof, fit, remeasure=remeasure, tell=tell, stop=stop, keep=keep, region=region
        )
    t0 = time.perf_counter()
    plan = announce(prof, fit, targets, region)
    (mu_t, s2_t), vt, warnings = plan.point, plan.targets, plan.warnings
    said = {"targets": vt, "announced": plan.announced, "requested": plan.requested, "source": table}
    if targets.is_identity() or plan.nothing_to_do:
        if plan.nothing_to_do:
            warnings.append("nothing to do: the request was clamped back to the material's own fit")
        out = table.copy()
        out.path = None
        flags = {"clamped": True, "nothing_to_do": True} if plan.nothing_to_do else {}
        res = _finish(out, mu_t, s2_t, warnings, prof, remeasure, vt, **said, **flags)
        tell(1, 1)
        return res
    if targets.is_energy_only() or (plan.at_fit and targets.grazing_boost == 1.0):
        # Energy only (or lobes clamped back to the fit): the specular part scales exactly.
        kd = np.asarray(prof.kd, float) if prof.split else np.zeros(3)
        spec = np.maximum(table.rho - kd[:, None], 0.0)
        gain = targets.strength * np.asarray(targets.colour, float)[:, None]
        rho = np.where(table.valid, np.minimum(table.rho, kd[:, None]) + gain * spec, 0.0)
        out = MerlTable(rho, table.valid.copy(), None)
        res = _finish(out, mu_t, s2_t, warnings, prof, remeasure, vt, **said, clamped=plan.clamped)
        tell(1, 1)
        return res
    region, clamped = plan.region, plan.clamped
    tell(1, 3)
    t_reg = time.perf_counter() - t0
    key = _synthesis_key(table, prof, fit, vt) if keep and not draft else None
    kept = _KEPT.get(key) if key is not None else None
    if kept is not None:
        out = kept.copy()  # the caller owns its table
    else:
        with one_thread():  # its dense algebra is tiny: OpenBLAS's thread hand-offs cost more
            out = synthesize(table, prof, fit, vt, draft=draft, stop=stop)[0]
        if key is not None:
            _KEPT.clear()
            _KEPT[key] = out.copy()
    t_syn = time.perf_counter() - t0
    tell(2, 3)
    res = _finish(
        out,
        mu_t,
        s2_t,
        warnings,
        prof,
        remeasure,
        vt,
        draft=draft,
        region=region,
        clamped=clamped,
        timings={"synthesis": t_syn, "region": t_reg},
        reused=kept is not None,
        **said,
    )
    tell(3, 3)
    return res


def is_roughness_edit(targets: EditTargets) -> bool:
    """A variance or mean-slope move in warp mode: SPEC §3's roughness edit (the mean slope
    follows the roughness), then the tilt when the mean slope is moved off that curve. The
    energy sliders may move with them."""
    moved = targets.sigma2 is not None or targets.roughness is not None or targets.mu_slope is not None
    return targets.mode == "warp" and moved and not targets.lock


def measured_targets(new_prof: Profiles, mu: float, s2: float) -> ViewTargets:
    """The per-view promise of a roughness edit: the figures measured on the table it makes
    (SPEC §3, "the sliders tell the truth"), shape included (shape follows the material)."""
    from .targets import SHAPE_KEYS, _stack

    st = lambda k: np.nan_to_num(_stack(new_prof, k))  # noqa: E731
    avg = new_prof["avg"]
    return ViewTargets(
        np.asarray(new_prof.theta_o, float),
        st("alpha"),
        st("mu_theta"),
        st("sigma_tt"),
        st("sigma_pp"),
        {k: st(k) for k in SHAPE_KEYS},
        "warp",
        float(mu),
        float(s2),
        np.nan_to_num(np.asarray(avg["mu_theta"], float)),
        np.nan_to_num(0.5 * (np.asarray(avg["sigma_tt"], float) + np.asarray(avg["sigma_pp"], float))),
    )


# The tilt moves each view's mean by tilt * theta_o up to TILT_FADE[0], fading to nothing at
# TILT_FADE[1]: near the horizon a lobe cannot be moved further without crossing it.
TILT_FADE = (math.radians(70.0), math.radians(89.0))


def tilt_lobes(table, prof: Profiles, fit: dict, tilt: float, stop=None):
    """SPEC §3's mean-slope move off the material's curve: the reciprocal per-view transform
    (``reciprocal``) asked to move every view's mean by ``tilt`` theta_o (faded near the
    horizon) and to keep its energy and variance as the table has them. Returns (table,
    profiles, fit), the last two a fresh analysis of the tilted table."""
    from .scale import measure as measure_table

    theta = np.asarray(prof.theta_o, float)
    x = np.clip((theta - TILT_FADE[0]) / (TILT_FADE[1] - TILT_FADE[0]), 0.0, 1.0)
    shift = tilt * theta * (1.0 - x * x * (3.0 - 2.0 * x))
    vt = measured_targets(prof, fit["mu_slope"] + tilt, fit["sigma2"])
    vt.mean = vt.mean + shift[:, None]
    vt.avg_mean = vt.avg_mean + shift
    out = synthesize(table, prof, fit, vt, stop=stop)[0]
    out = _cap_horizon_growth(out, table, np.asarray(prof.kd, float) if prof.split else np.zeros(3))
    new_prof, new_fit = measure_table(out, prof.theta_o, prof.split)
    return out, new_prof, new_fit


HORIZON_COS = 0.06  # the band near the horizon where a transform may not raise cells beyond the peak


def _cap_horizon_growth(out, before, kd):
    """SPEC §3: near the horizon no cell grows by more than the lobe's peak does. The tilt's
    factor is largest there (a cell may rise e^3 by the transform's own bound); cells of the band
    are capped at their value before times the specular peak's growth."""
    band, inner = _horizon_band()
    k = np.asarray(kd, float)[:, None]
    # max(rho - kd, 0) over cells is max(max rho - kd, 0): rounding is monotone.
    peak_new = np.maximum(_inner_max(out.rho, band, inner) - k[:, 0], 0.0)
    peak_old = np.maximum(_inner_max(before.rho, band, inner) - k[:, 0], 0.0)
    growth = np.maximum(peak_new / np.maximum(peak_old, 1e-300), 1.0)[:, None]
    new = out.rho - k
    np.maximum(new, 0.0, out=new)
    new[:, band] = np.minimum(new[:, band], np.maximum(before.rho[:, band] - k, 0.0) * growth)
    new += k
    new *= out.valid  # missing cells 0
    return MerlTable(new, out.valid.copy(), None)


def _inner_max(rho, band, inner):
    """(3,) the largest value of each channel outside the horizon band: the whole channel's
    maximum where the band's is below it (no gather of the inner cells), else taken over them."""
    whole, edge = rho.max(axis=1), rho[:, band].max(axis=1)
    return np.array([whole[c] if whole[c] > edge[c] else rho[c, inner].max() for c in range(len(rho))])


def _horizon_band():
    """The flat cell indices within HORIZON_COS of the horizon, and those outside it (once)."""
    if "band" not in _BAND:
        from .microfacet import cell_cosines

        low = np.minimum(*cell_cosines()).ravel()
        _BAND["band"] = (np.flatnonzero(low < HORIZON_COS), np.flatnonzero(low >= HORIZON_COS))
    return _BAND["band"]


_BAND: dict = {}


MU_MET = 0.002  # a mean slope this close to the request is met (SPEC §6: within 0.002)
TILT_LIMIT = 4.0  # the transform is asked for at most this many times the move requested
TILT_MAX = 0.3  # and never for more than this: beyond, the per-view solve pushes cells to the horizon


def solve_tilt(table, prof: Profiles, fit: dict, want: float, stop=None):
    """The tilt whose table re-fits to a mean slope ``want`` away from ``fit``'s: one pass, and
    one secant correction when the first falls short (a reciprocal transform moves a lobe less
    than asked: the lobe's image under the swap of the directions holds it to the mirror).
    Returns (tilt asked, table, profiles, fit) of the pass that came closest."""
    mu0 = float(fit["mu_slope"])
    best = None
    tilt = float(np.clip(want, -TILT_MAX, TILT_MAX))
    for _ in range(2):
        out, p, f = tilt_lobes(table, prof, fit, tilt, stop=stop)
        got = f.get("mu_slope")
        if got is None:
            break
        miss = abs(got - mu0 - want)
        if best is None or miss < best[0]:
            best = (miss, tilt, out, p, f)
        moved = got - mu0
        if miss <= MU_MET or abs(moved) < 1e-6 or moved * want <= 0:
            break
        lim = min(TILT_LIMIT * abs(want), TILT_MAX)
        tilt = float(np.clip(tilt * want / moved, -lim, lim))
    if best is None:
        return 0.0, table, prof, fit
    return best[1], best[2], best[3], best[4]


def _source_or_refuse(table, prof):
    src = roughness_source(table, prof)
    if src is None:
        raise ValueError(
            f"{table.name or 'the table'}: no microfacet lobe to read in it, so its roughness cannot be edited "
            "(strength and colour still can)"
        )
    return src


def roughness_point(targets: EditTargets, fit: dict, region: ReachableRegion | None):
    """((mu, sigma2) asked, (mu, sigma2) the edit makes, warnings) of a roughness edit: with a
    region built on the material's curve, a point outside it goes to its nearest point (the mean
    slope, when not moved, is the curve's own at that variance); without one, the request."""
    mu, s2, warnings = resolve_targets(targets, fit)
    if region is None or not region.curve:
        return (mu, s2), (mu, s2), warnings
    on_curve = targets.mu_slope is None and region.curve_mu(s2) is not None
    if on_curve:
        mu = region.curve_mu(s2)
    mu_c, s2_c, moved = region.clamp(mu, s2)
    if on_curve:
        mu_c = region.curve_mu(s2_c)
    if moved:
        warnings.append(
            f"mean slope {mu:+.3f} and variance {s2:.4g} lie outside what this material's roughness edit and "
            f"tilt reach: clamped to the nearest reachable point ({mu_c:+.3f}, {s2_c:.4g})"
        )
    return (mu, s2), (mu_c, s2_c), warnings


def roughness_edit(
    table,
    targets: EditTargets,
    prof: Profiles,
    fit: dict,
    remeasure=True,
    tell=None,
    stop=None,
    keep=False,
    region: ReachableRegion | None = None,
):
    """SPEC §3's variance edit: the roughness scale s whose table re-fits to the requested
    sigma~^2 (``scale.solve_scale``), the energy sliders on its specular part, and the
    announcement measured on that table. A request the operator cannot reach ends at the
    nearest scale it reaches and is reported as clamped."""
    from .roughness import S_RANGE, bound_energy
    from .scale import at_scale, solve_scale
    from .scale import measure as measure_table

    tell = tell or (lambda done, total: None)
    asked, (mu_r, s2_r), warnings = roughness_point(targets, fit, region)
    region_clamped = asked != (mu_r, s2_r)
    if region_clamped and targets.sigma2 is not None:
        targets = dataclasses.replace(targets, sigma2=s2_r)
    if region_clamped and targets.mu_slope is not None:
        targets = dataclasses.replace(targets, mu_slope=mu_r)
    t0 = time.perf_counter()
    src = _source_or_refuse(table, prof)
    tell(1, 3)
    t_src = time.perf_counter() - t0
    key = (source_key(), repr(targets)) if keep else None
    kept = _KEPT.get(key) if key is not None else None
    if kept is not None:
        tell(2, 3)  # the synthesis stage: a lookup (the stages are still reported, in order)
        res = dataclasses.replace(kept, table=kept.table.copy(), warnings=list(kept.warnings), reused=True)
        if remeasure and res.fidelity is None:
            res.fidelity = measure(res.profiles, res.targets, prof, reachable=np.ones_like(res.targets.alpha, bool))
            res.fidelity.judge_far = False
        tell(3, 3)
        return res
    with one_thread():
        if targets.roughness is not None:
            sol = at_scale(src, targets.roughness, prof.theta_o, prof.split)
            s2_r = sol.fit.get("sigma2") or s2_r  # a scale asked for directly: its variance is the request
        elif targets.sigma2 is not None:
            sol = solve_scale(src, s2_r, prof.theta_o, float(fit["sigma2"]), split=prof.split, stop=stop)
        else:
            sol = at_scale(src, 1.0, prof.theta_o, prof.split)  # the mean slope alone: the tilt only
    if sol is None:
        raise ValueError(f"{table.name}: the roughness edit found no lobe in the edited table")
    out = sol.table
    gain = targets.strength * np.asarray(targets.colour, float)
    new_prof, new_fit = sol.profiles, sol.fit
    clamped = region_clamped
    tilt = 0.0
    tilt_bounded = 0
    if targets.mu_slope is not None and new_fit.get("mu_slope") is not None:
        want = float(mu_r - new_fit["mu_slope"])
        if abs(want) > MU_MET:
            with one_thread():
                tilt, out, new_prof, new_fit = solve_tilt(out, new_prof, new_fit, want, stop=stop)
                # The tilt keeps each view's energy as a moment, not its albedo: a lobe moved
                # towards the horizon can return more than it receives (acrylic_felt_orange's
                # joint move reached 1.151), so it takes the operator's passivity bound too.
                out, tilt_bounded = bound_energy(src, out)
                if tilt_bounded:
                    new_prof, new_fit = measure_table(out, prof.theta_o, prof.split)
            if abs(new_fit["mu_slope"] - mu_r) > MU_MET:
                clamped = True
                warnings.append(
                    f"mean slope {mu_r:+.4f} is beyond what a reciprocal tilt of this lobe reaches: it re-fits "
                    f"to {new_fit['mu_slope']:+.4f}"
                )
    if np.any(gain != 1.0):
        kd = src.kd[:, None]
        rho = np.where(out.valid, kd + gain[:, None] * np.maximum(out.rho - kd, 0.0), 0.0)
        out = MerlTable(rho, out.valid.copy(), None)
        new_prof, new_fit = measure_table(out, prof.theta_o, prof.split)
    t_syn = time.perf_counter() - t0
    tell(2, 3)
    achieved = (new_fit.get("mu_slope"), new_fit.get("sigma2"))
    clamped = clamped or not sol.converged
    if not sol.converged:
        edge = "smoother" if s2_r < fit["sigma2"] else "rougher"
        where = "the table's theta_h cells" if sol.scale <= S_RANGE[0] * 1.001 or s2_r < fit["sigma2"] else "Lambertian"
        warnings.append(
            f"variance {s2_r:.4g} is beyond what a {edge} microsurface of this material shows (limit: {where}): "
            f"the nearest it reaches is {achieved[1]:.4g} (roughness x{sol.scale:.3g})"
        )
    vt = measured_targets(new_prof, mu_r, s2_r)
    albedo = directional_albedo(out, prof.theta_o, ALBEDO_STRIDE).max(axis=0)
    if np.any(albedo > 1.0):
        warnings.append(
            f"the edited material reflects more than it receives (largest directional albedo {albedo.max():.3f} "
            "> 1): lower its strength"
        )
    fid = None
    if remeasure:
        reach = np.ones_like(vt.alpha, dtype=bool)
        fid = measure(new_prof, vt, prof, reachable=reach, tables=(out, table))
        fid.judge_far = False
    res = EditResult(
        out,
        mu_r,
        s2_r,
        achieved[0],
        achieved[1],
        albedo,
        warnings,
        new_prof,
        fid,
        clamped=clamped,
        requested=asked,
        timings={"synthesis": t_syn, "source": t_src},
        targets=vt,
        announced=achieved,
    )
    note = _roughness_energy_note(new_prof, prof)
    if note:
        warnings.append(note)
    # What the panel showed before Apply (the curve's mean slope, the request's variance) against
    # what the table re-fits to: said when they differ (the curve is interpolated between its
    # ladder's scales).
    said_mu = mu_r if targets.mu_slope is not None else (region.curve_mu(s2_r) if region is not None else None)
    miss = _target_note(achieved[0], achieved[1], said_mu, s2_r)
    if miss:
        warnings.append(miss)
    res.operator = {
        "roughness_scale": float(sol.scale),
        "floor": [float(v) for v in src.kd],
        "floor_of_paper": [float(v) for v in src.floor_scale],
        "masking": src.reading.form,
        "reading_misfit": float(src.reading.misfit),
        "tilt": tilt,
        "tilt_energy_bounded_views": int(tilt_bounded),
        "solve_steps": int(sol.steps),
        "clamped": bool(clamped),
        "faded_cells": int(sol.report.get("faded_cells", 0)),
    }
    if key is not None:
        _KEPT.clear()
        _KEPT[key] = dataclasses.replace(res, table=res.table.copy(), warnings=list(res.warnings))
    tell(3, 3)
    return res


def roughness_draft(table, targets: EditTargets, prof: Profiles, fit: dict, region=None) -> EditResult:
    """The live preview's first image of a roughness edit: one synthesis at the scale the
    material's curve gives for the request (no solve, no tilt, nothing measured); the full edit
    follows it."""
    from .roughness import S_RANGE, scale_roughness
    from .scale import first_guess

    mu_r, s2_r, warnings = resolve_targets(targets, fit)
    src = _source_or_refuse(table, prof)
    if targets.roughness is not None:
        s = float(targets.roughness)
    elif targets.sigma2 is not None:
        curve = region.curve if region is not None else None
        if curve:
            from .scale import MaterialCurve

            c = MaterialCurve(
                *(np.array([np.nan if v is None else v for v in curve[k]], float) for k in ("scales", "mu", "sigma2"))
            )
            s = c.scale_for(s2_r) if c.usable().sum() >= 2 else first_guess(s2_r, fit["sigma2"])
        else:
            s = first_guess(s2_r, fit["sigma2"])
    else:
        s = 1.0
    s = float(np.clip(s, *S_RANGE))
    out = scale_roughness(src, s)[0]
    gain = targets.strength * np.asarray(targets.colour, float)
    if np.any(gain != 1.0):
        kd = src.kd[:, None]
        out = MerlTable(
            np.where(out.valid, kd + gain[:, None] * np.maximum(out.rho - kd, 0.0), 0.0), out.valid.copy(), None
        )
    return EditResult(out, mu_r, s2_r, None, None, np.full(3, np.nan), warnings, requested=(mu_r, s2_r))


def _roughness_energy_note(new_prof: Profiles, prof: Profiles):
    """A warning naming the views (holding >= 1e-6 of the peak) whose energy a roughness edit
    changed by more than ENERGY_WARNING: physics (masking, the horizon), said so the artist
    knows; the announcement carries the new energies."""
    got = np.nan_to_num(np.asarray(new_prof["avg"]["alpha"], float))
    was = np.nan_to_num(np.asarray(prof["avg"]["alpha"], float))
    use = was > 1e-6 * max(float(was.max(initial=0.0)), 1e-300)
    note = _views_off(prof.theta_o, got, was, use, "energy changes with the roughness")
    return None if note is None else note + " (masking and the horizon)"


def scale_to_albedo(result: EditResult, limit: float = 1.0) -> EditResult:
    """Scale the edited table down so its largest directional albedo is ``limit`` (kd too)."""
    import dataclasses

    from ..limits import RANGES

    limit = RANGES["albedo_limit"].check(limit, "limit")

    peak = float(result.max_albedo.max())
    if peak <= limit:
        return result
    f = limit / peak
    return dataclasses.replace(
        result,
        table=MerlTable(result.table.rho * f, result.table.valid.copy(), None),
        max_albedo=result.max_albedo * f,
        warnings=[w for w in result.warnings if "reflects more" not in w],
        fidelity=None,
        timings=dict(result.timings),
    )


REGION_TILT = 0.1  # the tilt asked for each way when the region's width in mean slope is measured
REGION_WORKERS = 2  # the region's tasks side by side (this machine's cores; more only adds memory)


def roughness_region(table, prof, fit, src=None, stop=None):
    """Warp mode's reachable region (SPEC §3): the material's curve in sigma~^2, and in mean
    slope the curve widened by what the tilt reaches each way (measured once, on the table
    itself, for a tilt of REGION_TILT). Computed once per analysis. None when the table holds
    no lobe a microfacet reading can read."""
    import contextlib
    import os
    from concurrent.futures import Future, ThreadPoolExecutor

    from .. import threads
    from .scale import material_curve
    from .scale import measure as measure_table
    from .scale import own as own_of_source

    # The tilt's run, the reading (when not made yet) and the curve's points are independent
    # and spend most of their time in numpy, which lets go of the GIL: on two cores side by
    # side they take about three quarters of the time they take in order (colodur_kalahari_2a,
    # reading made: 6.0-6.3 s in order, 4.5-5.0 s side by side, quiet). The tilt, the longest,
    # starts first, on the table's own measurement, while this thread makes the reading. The
    # pool is the region's own: the tilt's sums use reciprocal's, and a task waiting on its
    # own pool could wait for ever.
    workers = min(REGION_WORKERS, os.cpu_count() or 1)
    pool = (
        ThreadPoolExecutor(workers, thread_name_prefix="brdf_moments-region", initializer=threads.keep_in_order)
        if workers > 1
        else None
    )
    own: Future = Future()
    given_up = []  # set when the region is not wanted after all: the tilt stops at its next step
    halt = lambda: bool(given_up) or (stop is not None and stop())  # noqa: E731

    def own_then_tilt():
        try:
            own.set_result(measure_table(table, prof.theta_o, prof.split))
        except BaseException as err:
            own.set_exception(err)
            raise
        if halt():
            raise R.Superseded
        own_prof, own_fit = own.result()
        # The tilt's reach, measured one way and taken as the same the other (ggx_glossy:
        # 0.038 and 0.035 for +-0.1): half the cost of the region's tilt runs.
        return tilt_lobes(table, own_prof, own_fit, REGION_TILT, stop=halt)

    # Two threads of our own already fill this machine's cores: OpenBLAS's pool beside them
    # only waits for a core, and doubles the CPU it takes (colodur_kalahari_2a: 4.1 s and
    # 8.0 s of CPU with it, 3.7 s and 6.6 s without; the numbers the same to the bit).
    # For the same reason the engine's own pool (``threads``) stays out of the region's threads.
    with one_thread() if pool else contextlib.nullcontext(), threads.in_order() if pool else contextlib.nullcontext():
        try:
            tilt = pool.submit(own_then_tilt) if pool else None
            read_here = src is None
            if src is None:
                src = roughness_source(table, prof)
            if src is None:  # nothing a microsurface reading can hold (a table of a few cells)
                return None
            if tilt is None:
                tilted = own_then_tilt()
            curve = material_curve(src, prof.theta_o, prof.split, stop=halt, fit1=own.result()[1], pool=pool)
            if tilt is not None:
                tilted = tilt.result()
            if read_here or src.table is table:  # the source of this table: Apply's mean-slope moves reuse it
                own_of_source(src, prof.theta_o, prof.split, made=own.result())
        finally:
            given_up.append(True)  # done, or leaving on an error: nothing more of the tilt is wanted
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
    own_fit = own.result()[1]
    got = tilted[2].get("mu_slope")
    reach = [0.0 if got is None else abs(got - own_fit["mu_slope"])] * 2
    ok = curve.usable()
    order = np.argsort(curve.sigma2[ok])
    s2, mu = curve.sigma2[ok][order], curve.mu[ok][order]
    keep = np.concatenate([[True], np.diff(s2) > 0])
    s2, mu = s2[keep], mu[keep]
    return ReachableRegion(
        s2,
        mu - reach[0],
        mu + reach[1],
        float(s2.min()),
        float(s2.max()),
        (float(fit["mu_slope"]), float(fit["sigma2"])),
        curve=curve.to_json(),
    )
