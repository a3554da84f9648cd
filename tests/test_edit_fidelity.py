"""Editing per view (issue 18, SPEC §3 "Editing", §6): every view of the written table follows the
sliders, the table is reciprocal by construction, small slider moves make small table changes,
and requests outside the material's reachable region are clamped and said so.

The tolerances here are ones the replaced pipeline (per-view warps averaged per cell, removed on
2026-12-02) failed by far on the same requests (measured: ggx_glossy sigma2 x 0.5 gave a worst
energy error of 8 %, a median variance ratio error of 44 % and a worst one of 61 %; in model
mode at the fitted sliders, energy 29 %, variance 9 % / 17 %).
"""

import math

import numpy as np
import pytest

from addon.core.edit import EditTargets, edit
from addon.core.edit.fidelity import measure
from addon.core.file.merl import MerlTable, lookup
from addon.core.fits.curves import fit_material
from addon.core.geometry import view_centred
from addon.core.profiles.compute import compute_profiles

# Per view, worst of r, g, b over the counted views (5-80 deg, >= 5 % of the peak energy).
ENERGY = 0.03
VARIANCE_MEDIAN = 0.03
VARIANCE_WORST = 0.10


@pytest.fixture(scope="module")
def glossy(sample_table):
    table = sample_table("ggx_glossy")
    prof = compute_profiles(table)
    return table, prof, fit_material(prof)


@pytest.fixture(scope="module")
def narrowed(glossy):
    table, prof, fit = glossy
    return edit(table, EditTargets(sigma2=fit["sigma2"] * 0.5), prof, fit)


def _check_views(fid):
    assert fid.worst("energy") < ENERGY
    assert fid.worst("variance_median") < VARIANCE_MEDIAN
    assert fid.worst("variance_worst") < VARIANCE_WORST
    assert all(c.views >= 10 for c in fid.channels.values())  # a real number of views was judged


@pytest.mark.slow
def test_every_view_follows_a_variance_edit(narrowed):
    _check_views(narrowed.fidelity)
    assert not narrowed.clamped


@pytest.mark.slow
def test_fidelity_is_measured_on_the_written_table(glossy, narrowed, tmp_path):
    """The announcement is a measurement of the table the edit writes: the file written, read
    back and analysed afresh shows it, view by view (the stick is not the solver)."""
    from addon.core.file.merl import read_merl, write_merl
    from addon.core.profiles.compute import compute_profiles

    table, prof, fit = glossy
    path = tmp_path / "narrowed.binary"
    write_merl(narrowed.table, path)
    back = compute_profiles(read_merl(path), prof.theta_o)
    reach = np.ones_like(narrowed.targets.alpha, dtype=bool)
    again = measure(back, narrowed.targets, prof, reachable=reach)
    for ch in "rgb":
        c = again.channels[ch]
        assert c.views > 10
        assert c.energy < 1e-6 and c.variance_worst < 1e-6 and c.mean < 1e-7
        assert c.variance_worst == pytest.approx(narrowed.fidelity.channels[ch].variance_worst, abs=1e-6)


@pytest.mark.slow
def test_model_mode_runs_the_reciprocal_synthesis_to_the_models_targets(glossy):
    """Model mode at the fitted sliders: each view's target is the model's lobe (Eq. 7-8: the
    fitted energy spline, a Gaussian centred at mu~ theta_o of variance sigma~^2, clipped by the
    horizon). The synthesis holds the judged views' energy (3 %) and their median variance (5 %) up
    to 75 deg (single grazing views miss the variance by up to 11 %); the means
    of the grazing views, where the model's lobe sits 0.05-0.15 rad off the measured mirror lobe,
    are not asserted (BENCHMARKS, "Editing, per view")."""
    from addon.core.edit.fidelity import report
    from addon.core.edit.targets import model_lobe

    table, prof, fit = glossy
    res = edit(table, EditTargets(mode="model"), prof, fit)
    mean, var = model_lobe(prof.theta_o, fit["mu_slope"], fit["sigma2"], fit["mu_slope"], fit["sigma2"])
    np.testing.assert_allclose(res.targets.avg_mean, mean)
    rep = report(res, prof)
    theta = np.asarray(rep["theta_o"])
    use = np.asarray(rep["judged"]) & (theta <= np.radians(75.0) + 1e-9)
    assert use.sum() >= 10
    for ch in "rgb":
        got, want = (np.asarray(rep[k]["alpha"][ch], float) for k in ("achieved", "target"))
        assert np.abs(got / want - 1.0)[use].max() < ENERGY
        got, want = (np.asarray(rep[k]["variance"][ch], float) for k in ("achieved", "target"))
        assert np.median(np.abs(got / want - 1.0)[use]) < 0.05


@pytest.mark.slow
def test_every_view_follows_on_a_measured_material(sample_table):
    """satin_gold (RGL, decoded from its Neural-BRDF), sigma2 x 0.7. Measured on the same request,
    the replaced pipeline gave: energy 70 %, variance ratio 4.5 % median / 21 % worst. The mean
    is not asserted: the reciprocal synthesis misses it by 0.3-0.4 rad at 80 deg on this
    material (BENCHMARKS.md, issue 18: broad measured lobes at grazing views)."""
    table = sample_table("rgl/satin_gold")
    prof = compute_profiles(table)
    fit = fit_material(prof)
    res = edit(table, EditTargets(sigma2=fit["sigma2"] * 0.7), prof, fit)
    fid = res.fidelity
    assert fid.worst("energy") < 0.05
    assert fid.worst("variance_median") < 0.04
    assert fid.worst("variance_worst") < 0.18
    assert all(c.views >= 30 for c in fid.channels.values())


@pytest.mark.slow
def test_reciprocal_and_missing_cells_stay_missing(glossy):
    table, prof, fit = glossy
    valid = table.valid.copy()
    rng = np.random.default_rng(5)
    holes = rng.choice(valid.shape[1], 20000, replace=False)
    valid[:, holes] = False
    holed = MerlTable(np.where(valid, table.rho, 0.0), valid, None)
    res = edit(
        holed, EditTargets(sigma2=fit["sigma2"] * 0.6, mu_slope=fit["mu_slope"] + 0.02), prof, fit, remeasure=False
    )
    np.testing.assert_array_equal(res.table.valid, valid)
    assert np.all(res.table.rho[~valid] == 0.0)
    assert np.isfinite(res.table.rho).all() and (res.table.rho >= 0).all()
    wi = view_centred(rng.uniform(-1.4, 1.4, 3000), rng.uniform(-1.4, 1.4, 3000))
    wo = view_centred(rng.uniform(-1.4, 1.4, 3000), rng.uniform(-1.4, 1.4, 3000))
    a, _ = lookup(res.table, wi, wo)
    b, _ = lookup(res.table, wo, wi)
    np.testing.assert_array_equal(a, b)


def test_identity_and_energy_only_are_exact(glossy):
    table, prof, fit = glossy
    res = edit(table, EditTargets(), prof, fit)
    np.testing.assert_array_equal(res.table.rho, table.rho)
    assert res.fidelity.worst("variance_worst") < 1e-4  # the stick reads the identity as exact
    res = edit(table, EditTargets(strength=0.8), prof, fit)
    for ch in "rgb":
        np.testing.assert_allclose(res.profiles[ch]["alpha"], 0.8 * prof[ch]["alpha"], rtol=1e-5)


@pytest.mark.slow
def test_small_slider_moves_make_small_table_changes(glossy):
    """Continuity: a 1e-5 slider move changes the lit cells by ~1e-5 (measured 3e-5 median, so the
    bound is 10x that), a 0.1 % move by well under 1 %, and a 10 % move by far more. (With a
    piecewise-linear lookup and light damping, a 1e-7 move changed the table by 3e-4: the
    Gauss-Newton steps amplified it. The Catmull-Rom lookup and damping 0.3 fixed that.)"""
    table, prof, fit = glossy
    s2 = fit["sigma2"] * 0.6
    base = edit(table, EditTargets(sigma2=s2), prof, fit, remeasure=False).table.rho
    lit = base > 1e-3 * base.max()
    change = {}
    for d in (1e-5, 1e-3, 0.1):
        moved = edit(table, EditTargets(sigma2=s2 * (1 + d)), prof, fit, remeasure=False).table.rho
        diff = np.abs(moved - base)
        change[d] = (float(np.median(diff[lit] / base[lit])), float(diff.max() / base.max()))
    assert change[1e-5][0] < 3e-4
    assert change[1e-3][0] < 0.01 and change[1e-3][1] < 0.03
    assert change[0.1][0] > 5 * change[1e-3][0]


@pytest.mark.slow
def test_deterministic(glossy):
    table, prof, fit = glossy
    t = EditTargets(sigma2=fit["sigma2"] * 1.3)
    a = edit(table, t, prof, fit, remeasure=False).table.rho
    b = edit(table, t, prof, fit, remeasure=False).table.rho
    np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_requests_outside_the_region_are_clamped_and_said_so(glossy):
    """A mean slope far off the material's curve (a narrow lobe 0.87 off it) is beyond what a
    reciprocal tilt reaches: the edit goes as far as it can, says so, and announces where it
    landed (the written table's own fit)."""
    table, prof, fit = glossy
    far = EditTargets(mu_slope=-0.2, sigma2=fit["sigma2"] * 0.2)
    res = edit(table, far, prof, fit)
    assert res.clamped and res.requested == (-0.2, pytest.approx(fit["sigma2"] * 0.2))
    assert any("beyond what a reciprocal tilt" in w for w in res.warnings)
    assert res.announced == (res.achieved_mu_slope, res.achieved_sigma2)
    assert res.achieved_mu_slope < -0.2 - 0.5  # far from the request: nothing pretends otherwise
    assert abs(res.operator["tilt"]) <= 0.3 + 1e-12


@pytest.fixture(scope="module")
def glossy_region(glossy):
    from addon.core.edit.solve import roughness_region

    table, prof, fit = glossy
    return roughness_region(table, prof, fit)


@pytest.mark.parametrize("factor", [0.5, 1.25])
def test_the_draft_goes_most_of_the_way_and_stays_reciprocal(glossy, glossy_region, factor):
    """The live preview's draft (one synthesis at the scale the material's curve gives, nothing
    solved) is the same operator's table: reciprocal, deterministic, and it lands near the
    request (within 5 % in sigma~^2 with the curve; at least 60 % of the way in log sigma~^2 from
    the first guess without one, sigma~^2 as s^1.2)."""
    from addon.core.edit.scale import measure as analyse

    table, prof, fit = glossy
    t = EditTargets(sigma2=fit["sigma2"] * factor)
    draft = edit(table, t, prof, fit, draft=True, region=glossy_region)
    got = analyse(draft.table, prof.theta_o)[1]["sigma2"]
    assert got == pytest.approx(t.sigma2, rel=0.05)
    bare = edit(table, t, prof, fit, draft=True)
    got_bare = analyse(bare.table, prof.theta_o)[1]["sigma2"]
    assert math.log(got_bare / fit["sigma2"]) / math.log(factor) > 0.6
    again = edit(table, t, prof, fit, draft=True, region=glossy_region).table.rho
    np.testing.assert_array_equal(again, draft.table.rho)
    rng = np.random.default_rng(11)
    wi = view_centred(rng.uniform(-1.4, 1.4, 2000), rng.uniform(-1.4, 1.4, 2000))
    wo = view_centred(rng.uniform(-1.4, 1.4, 2000), rng.uniform(-1.4, 1.4, 2000))
    a, _ = lookup(draft.table, wi, wo)
    b, _ = lookup(draft.table, wo, wi)
    np.testing.assert_array_equal(a, b)


def test_an_energy_edit_of_a_broad_lobe_promises_its_own_variance(sample_table):
    """nielsen/greencloth fits sigma2 above the slider's pi^2/12. An energy-only edit leaves
    the variance alone: the promised per-view variance is the measured one (the bench found a
    22 % variance error here when the untouched variance was clamped to the slider's range)."""
    from addon.core.fits.curves import LAMBERT_VARIANCE

    table = sample_table("nielsen/greencloth")
    prof = compute_profiles(table)
    fit = fit_material(prof)
    assert fit["sigma2"] > LAMBERT_VARIANCE  # the case in question
    for t in (EditTargets(strength=0.8), EditTargets(colour=(1.0, 0.7, 0.4))):
        res = edit(table, t, prof, fit)
        assert res.target_sigma2 == fit["sigma2"] and not res.warnings
        assert res.fidelity.worst("variance_worst") < 1e-4 and res.fidelity.worst("energy") < 1e-4


@pytest.mark.slow
def test_the_region_side_by_side_is_the_region_in_order(glossy, glossy_region, monkeypatch):
    """The region's tilt and curve points run on two threads: the same numbers as one after
    another, and a stop asked for while they run ends every one of its threads."""
    import threading

    from addon.core.edit import solve
    from addon.core.edit.reciprocal import Superseded

    table, prof, fit = glossy
    monkeypatch.setattr(solve, "REGION_WORKERS", 1)
    in_order = solve.roughness_region(table, prof, fit)
    for a in ("sigma2", "mu_min", "mu_max"):
        np.testing.assert_array_equal(getattr(glossy_region, a), getattr(in_order, a))
    assert glossy_region.curve == in_order.curve
    monkeypatch.setattr(solve, "REGION_WORKERS", 2)
    asked = []

    def stop():
        asked.append(threading.current_thread().name)
        return len(asked) > 3  # after the first points have started, on both threads

    with pytest.raises(Superseded):
        solve.roughness_region(table, prof, fit, stop=stop)
    assert any(n.startswith("brdf_moments-region") for n in asked)
    assert not [t for t in threading.enumerate() if t.name.startswith("brdf_moments-region")]
