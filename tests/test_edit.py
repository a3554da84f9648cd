"""Editing (SPEC §3 "Editing"): properties that hold for every edit."""

import math

import numpy as np
import pytest

from addon.core.edit import EditTargets, directional_albedo, edit, scale_to_albedo
from addon.core.file.merl import lookup
from addon.core.fits import truncated
from addon.core.fits.curves import fit_material
from addon.core.geometry import view_centred
from addon.core.preview.lobe import truncnorm_pdf
from addon.core.profiles.compute import compute_profiles


@pytest.fixture(scope="module")
def glossy(sample_table):
    table = sample_table("ggx_glossy")
    prof = compute_profiles(table)
    return table, prof, fit_material(prof)


def test_identity_edit_returns_the_input_values_exactly(glossy):
    table, prof, fit = glossy
    before = table.rho.copy()
    res = edit(table, EditTargets(), prof, fit)
    np.testing.assert_array_equal(res.table.rho, table.rho)
    np.testing.assert_array_equal(res.table.valid, table.valid)
    np.testing.assert_array_equal(table.rho, before)  # the input is untouched
    assert res.achieved_mu_slope == pytest.approx(fit["mu_slope"], abs=1e-9)


def test_energy_scaling_is_exact(glossy):
    table, prof, fit = glossy
    res = edit(table, EditTargets(strength=0.5, colour=(1.0, 0.5, 0.25)), prof, fit)
    for i, ch in enumerate("rgb"):
        want = 0.5 * (1.0, 0.5, 0.25)[i] * prof[ch]["alpha"]
        np.testing.assert_allclose(res.profiles[ch]["alpha"], want, rtol=1e-5)
    # The shape is untouched: same mean and variance profiles.
    np.testing.assert_allclose(res.profiles["avg"]["mu_theta"], prof["avg"]["mu_theta"], atol=1e-6)
    np.testing.assert_allclose(res.profiles["avg"]["sigma_tt"], prof["avg"]["sigma_tt"], rtol=1e-5)


@pytest.mark.slow
@pytest.mark.parametrize("targets", [EditTargets(mu_slope=-0.95), EditTargets(mode="model", mu_slope=-1.0, sigma2=0.1)])
def test_edited_table_is_reciprocal_and_keeps_missing_cells(glossy, targets):
    table, prof, fit = glossy
    res = edit(table, targets, prof, fit)
    rng = np.random.default_rng(0)
    wi = view_centred(rng.uniform(-1.4, 1.4, 2000), rng.uniform(-1.4, 1.4, 2000))
    wo = view_centred(rng.uniform(-1.4, 1.4, 2000), rng.uniform(-1.4, 1.4, 2000))
    a, _ = lookup(res.table, wi, wo)
    b, _ = lookup(res.table, wo, wi)
    np.testing.assert_allclose(a, b, rtol=1e-12)
    np.testing.assert_array_equal(res.table.valid, table.valid)
    assert np.isfinite(res.table.rho).all() and (res.table.rho >= 0).all()


@pytest.mark.slow
@pytest.mark.parametrize(
    "targets",
    [
        # at the declared ranges' edges (core/limits.py; beyond them an edit is refused,
        # tests/test_stress_edit.py): 1e-8 is clamped to MIN_SIGMA2, -2 to the slider's end
        EditTargets(sigma2=1e-8),
        EditTargets(mu_slope=-1.0),
        EditTargets(mu_slope=0.0),
        EditTargets(mu_slope=-2.0, sigma2=math.pi**2 / 12),
        EditTargets(mode="model", mu_slope=0.0, sigma2=1e-8),
    ],
)
def test_degenerate_sliders_give_finite_valid_tables(glossy, targets):
    table, prof, fit = glossy
    res = edit(table, targets, prof, fit, remeasure=False)
    assert np.isfinite(res.table.rho).all() and (res.table.rho >= 0).all()
    assert np.isfinite(res.max_albedo).all()
    # Sliders that were set are clamped to their ranges ([-1, 0] widened to hold the fitted
    # slope, SPEC §3); an untouched one keeps the measurement.
    if targets.mu_slope is not None:
        assert min(-1.0, fit["mu_slope"]) <= res.target_mu_slope <= max(0.0, fit["mu_slope"])
    else:
        assert res.target_mu_slope == fit["mu_slope"]
    if targets.sigma2 is not None:
        assert 0.0 < res.target_sigma2 <= math.pi**2 / 12


def test_scale_to_albedo_brings_the_peak_to_one(glossy):
    table, prof, fit = glossy
    res = edit(table, EditTargets(strength=4.0), prof, fit, remeasure=False)
    assert res.energy_gain and any("reflects more" in w for w in res.warnings)
    fixed = scale_to_albedo(res)
    assert fixed.max_albedo.max() == pytest.approx(1.0)
    from addon.core.edit.solve import ALBEDO_STRIDE

    assert directional_albedo(fixed.table, prof.theta_o, ALBEDO_STRIDE).max() == pytest.approx(1.0, rel=1e-6)
    # The check's views are a subset: every view's albedo is at least close to it.
    assert directional_albedo(fixed.table, prof.theta_o).max() == pytest.approx(1.0, rel=0.02)


def test_truncated_gaussian_solver_matches_its_targets():
    mean_t = np.array([0.0, -0.5, -1.2])
    var_t = np.array([0.3, 0.05, 0.02])
    m, s, used = truncated.solve(mean_t, var_t)
    np.testing.assert_array_equal(used, var_t)  # none capped
    mt, vt = truncated.moments(m, s)
    np.testing.assert_allclose(mt, mean_t, atol=1e-7)
    np.testing.assert_allclose(vt, var_t, rtol=1e-5)
    from scipy.stats import truncnorm

    a, b = (-math.pi / 2 - m[1]) / s[1], (math.pi / 2 - m[1]) / s[1]
    assert truncnorm.mean(a, b, loc=m[1], scale=s[1]) == pytest.approx(-0.5, abs=1e-7)


@pytest.mark.parametrize("m, s", [(0.0, 0.3), (1.2, 0.5), (-3.0, 0.2), (-6.0, 0.05), (0.0, 100.0)])
def test_truncated_moments_and_density_agree_with_scipy_far_into_the_tails(m, s):
    # Lobes centred beyond the horizon (m = -6, s = 0.05: all the mass in a far-tail sliver)
    # are where a naive erf difference divides zero by zero.
    from scipy.stats import truncnorm

    a, b = (-math.pi / 2 - m) / s, (math.pi / 2 - m) / s
    ref = truncnorm(a, b, loc=m, scale=s)
    mt, vt = truncated.moments(np.array([m]), np.array([s]))
    assert mt[0] == pytest.approx(ref.mean(), abs=1e-9)
    assert vt[0] == pytest.approx(ref.var(), rel=1e-6)
    x = np.linspace(-1.5, 1.5, 7)
    g = truncnorm_pdf(x, np.full(7, m), np.full(7, s))
    assert np.isfinite(g).all()
    with np.errstate(divide="ignore", invalid="ignore"):
        logref = ref.logpdf(x)
    finite = logref > -700  # below that the density underflows to 0, as it should
    np.testing.assert_allclose(np.log(g[finite]), logref[finite], rtol=1e-9, atol=1e-9)


@pytest.mark.slow
def test_reported_moments_are_the_written_tables(glossy, tmp_path):
    """What the edit reports (fit and per-view figures) is what re-reading the written file shows."""
    from addon.core.file.merl import read_merl, write_merl

    table, prof, fit = glossy
    res = edit(table, EditTargets(sigma2=fit["sigma2"] * 0.8), prof, fit)
    path = tmp_path / "e.binary"
    write_merl(res.table, path)
    # A fresh analysis of the file, its own floor included: what anyone loading it sees.
    again = compute_profiles(read_merl(path), prof.theta_o)
    f = fit_material(again)
    assert res.achieved_mu_slope == pytest.approx(f["mu_slope"], abs=1e-6)
    assert res.achieved_sigma2 == pytest.approx(f["sigma2"], rel=1e-5)


@pytest.mark.slow
def test_a_kept_synthesis_is_reused_only_for_the_same_inputs(glossy):
    """``keep=True`` (the live preview, then Apply): an Apply of the same sliders writes the kept
    table, bit for bit what solving again gives, even from a table read afresh; other sliders or
    another table solve again; without ``keep`` (the CLI, the benchmarks) nothing is reused."""
    from addon.core.edit import solve

    table, prof, fit = glossy
    targets = EditTargets(sigma2=fit["sigma2"] * 1.2)
    fresh = edit(table, targets, prof, fit, remeasure=False)
    assert not fresh.reused
    solve._KEPT.clear()
    first = edit(table, targets, prof, fit, remeasure=False, keep=True)
    assert not first.reused and len(solve._KEPT) == 1
    again = edit(table.copy(), targets, prof, fit, keep=True)  # another object, same content
    assert again.reused
    np.testing.assert_array_equal(again.table.rho, fresh.table.rho)
    assert again.profiles is not None  # re-measured all the same
    again.table.rho[:] = 0.0  # the caller owns what it got: the kept table is untouched
    assert edit(table, targets, prof, fit, keep=True).table.rho.max() > 0
    assert not edit(table, targets, prof, fit).reused  # not asked to keep: solved again
    assert not edit(table, EditTargets(sigma2=fit["sigma2"] * 1.21), prof, fit, keep=True).reused
    other = table.copy()
    other.rho[0, np.flatnonzero(other.valid)[0]] *= 1.5
    assert not edit(other, targets, prof, fit, keep=True).reused
    solve._KEPT.clear()


def test_a_superseded_synthesis_stops_between_its_steps_and_keeps_nothing(glossy):
    """``stop()`` (the live preview's "a newer move came") is asked before every step of the
    roughness solve: once it says so the edit raises ``Superseded`` at once, and a stop that
    never fires changes nothing in the table."""
    from addon.core.edit import Superseded

    table, prof, fit = glossy
    targets = EditTargets(sigma2=fit["sigma2"] * 0.5)  # three secant steps (x0.8: the first guess lands)
    asked = []

    def never():
        asked.append(1)
        return False

    plain = edit(table, targets, prof, fit, remeasure=False)
    watched = edit(table, targets, prof, fit, remeasure=False, stop=never)
    np.testing.assert_array_equal(watched.table.rho, plain.table.rho)
    steps = watched.operator["solve_steps"]
    assert steps >= 2 and len(asked) == steps  # asked before each step, not only at the end

    for k in range(1, steps + 1):
        calls = []

        def at_k(k=k, calls=calls):
            calls.append(1)
            return len(calls) >= k

        with pytest.raises(Superseded):
            edit(table, targets, prof, fit, remeasure=False, stop=at_k)
        assert len(calls) == k  # gave up at the k-th question, not after the remaining steps


def test_the_live_work_drops_a_superseded_refinement(glossy):
    """``preview.live.work``: a move that comes once the full synthesis has started stops it at
    its next step (nothing is kept, no refined image of the old sliders is posted), rather than
    after the whole synthesis."""
    from addon.core.edit import solve
    from addon.core.preview.envmap import Environment
    from addon.core.preview.live import work

    table, prof, fit = glossy
    targets = EditTargets(sigma2=fit["sigma2"] * 0.8)
    posted, asked_after_live = [], []

    def stale():
        if posted:
            asked_after_live.append(1)
        return len(asked_after_live) > 1  # the move comes just after the full synthesis began

    solve._KEPT.clear()
    env = Environment(np.full((8, 16, 3), 0.5))
    work(table, targets, prof, fit, env, 16, stale=stale, post=lambda s, rgb, cov: posted.append(s))
    assert posted == ["live"]
    assert not solve._KEPT  # the full synthesis (keep=True) did not run to its end
    assert len(asked_after_live) == 2
