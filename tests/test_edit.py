"""Editing (SPEC §3 "Editing"): properties that hold for every edit."""

import math

import numpy as np
import pytest

from addon.core.edit import EditTargets, directional_albedo, edit, scale_to_albedo, solve_truncated, _trunc_moments
from addon.core.fits import fit_material
from addon.core.merl import lookup
from addon.core.geometry import view_centred
from addon.core.profiles import compute_profiles


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
@pytest.mark.parametrize("targets", [
    EditTargets(sigma2=1e-12), EditTargets(mu_slope=-1.0), EditTargets(mu_slope=0.0),
    EditTargets(mu_slope=-3.0, sigma2=50.0), EditTargets(mode="model", mu_slope=0.0, sigma2=1e-9),
])
def test_degenerate_sliders_give_finite_valid_tables(glossy, targets):
    table, prof, fit = glossy
    res = edit(table, targets, prof, fit, max_rounds=1)
    assert np.isfinite(res.table.rho).all() and (res.table.rho >= 0).all()
    assert np.isfinite(res.max_albedo).all()
    # Sliders that were set are clamped to their ranges; an untouched one keeps the measurement.
    if targets.mu_slope is not None:
        assert -1.0 <= res.target_mu_slope <= 0.0
    else:
        assert res.target_mu_slope == fit["mu_slope"]
    if targets.sigma2 is not None:
        assert 0.0 < res.target_sigma2 <= math.pi ** 2 / 12


def test_scale_to_albedo_brings_the_peak_to_one(glossy):
    table, prof, fit = glossy
    res = edit(table, EditTargets(strength=4.0), prof, fit, remeasure=False)
    assert res.energy_gain and any("reflects more" in w for w in res.warnings)
    fixed = scale_to_albedo(res)
    assert fixed.max_albedo.max() == pytest.approx(1.0)
    assert directional_albedo(fixed.table).max() == pytest.approx(1.0, rel=1e-6)


def test_truncated_gaussian_solver_matches_its_targets():
    mean_t = np.array([0.0, -0.5, -1.2])
    var_t = np.array([0.3, 0.05, 0.02])
    m, s, ok = solve_truncated(mean_t, var_t)
    assert ok.all()
    mt, vt = _trunc_moments(m, s)
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
    from addon.core.edit import _truncated_gauss

    a, b = (-math.pi / 2 - m) / s, (math.pi / 2 - m) / s
    ref = truncnorm(a, b, loc=m, scale=s)
    mt, vt = _trunc_moments(np.array([m]), np.array([s]))
    assert mt[0] == pytest.approx(ref.mean(), abs=1e-9)
    assert vt[0] == pytest.approx(ref.var(), rel=1e-6)
    x = np.linspace(-1.5, 1.5, 7)
    g = _truncated_gauss(x, np.full(7, m), np.full(7, s))
    assert np.isfinite(g).all()
    with np.errstate(divide="ignore", invalid="ignore"):
        logref = ref.logpdf(x)
    finite = logref > -700  # below that the density underflows to 0, as it should
    np.testing.assert_allclose(np.log(g[finite]), logref[finite], rtol=1e-9, atol=1e-9)


def test_warp_to_the_measured_moments_reproduces_the_table(sample_table):
    # Not the identity shortcut: the full warp path with sliders set to the measured values
    # must solve to the identity map, so the table (and its moments) come back unchanged.
    # ggx_rough: its slope is inside [-1, 0], so the sliders are not clamped away from it.
    from addon.core.edit import synthesize

    table = sample_table("ggx_rough")
    prof = compute_profiles(table)
    fit = fit_material(prof)
    assert -1.0 < fit["mu_slope"] < 0.0
    targets = EditTargets(mu_slope=fit["mu_slope"], sigma2=fit["sigma2"])
    out, _ = synthesize(table, targets, prof, fit)
    on = table.valid.any(axis=0)
    # The specular part is max(rho - kd, 0) (SPEC §3), so cells below kd come back as kd.
    expected = np.maximum(table.rho, np.asarray(prof.kd)[:, None])
    np.testing.assert_allclose(out.rho[:, on], expected[:, on], rtol=1e-9, atol=1e-12)


# --- moment round trips: edit, write, read back, re-measure, compare with the targets ----------
# The tolerances: |d mu| < 0.01 and |d sigma2| / sigma2 < 2 %.

def _remeasured(res, prof, tmp_path):
    from addon.core.merl import read_merl, write_merl

    path = tmp_path / "edited.binary"
    write_merl(res.table, path)
    again = compute_profiles(read_merl(path), prof.theta_o, kd=prof.kd if prof.split else None, split=prof.split)
    res.remeasured = again
    return fit_material(again)


SHAPE_KEYS = ("skew_30", "skew_12", "kurt_40", "kurt_22", "kurt_04")  # the others are 0 by symmetry


def _shape_change(before, after, max_deg=60.0):
    """Per standardized moment: the largest change over views up to max_deg, relative to the
    largest value the input's profile takes there."""
    sel = np.degrees(np.asarray(before.theta_o)) <= max_deg
    out = {}
    for key in SHAPE_KEYS:
        b, a = (np.asarray(p["avg"][key], float)[sel] for p in (before, after))
        out[key] = float(np.nanmax(np.abs(a - b)) / np.nanmax(np.abs(b)))
    return out


@pytest.mark.parametrize("mode, name, scale", [
    ("model", "ggx_mirror", 0.7), ("model", "ggx_mirror", 1.3), ("model", "ggx_glossy", 0.7),
    ("model", "ggx_glossy", 1.3), ("model", "ggx_rough", 0.7), ("warp", "ggx_mirror", 0.7),
    ("warp", "ggx_mirror", 1.3),
    # At a fold, met by 0.0006 with operator version 7 (d mu +0.0094); the cell-exact profiles
    # of version 8 re-measure it at 0.0110. Strict: it must be looked at, not hidden.
    pytest.param("warp", "ggx_glossy", 0.7, marks=pytest.mark.xfail(
        strict=True, reason="d mu 0.011 > 0.01 with operator version 8 (issue 20); the edit's fold case")),
    ("warp", "ggx_glossy", 1.3), ("warp", "ggx_rough", 0.7)])
def test_variance_edit_round_trips(sample_table, tmp_path, mode, name, scale):
    from addon.core.edit import target_energy

    table = sample_table(name)
    prof = compute_profiles(table)
    fit = fit_material(prof)
    targets = EditTargets(sigma2=fit["sigma2"] * scale, mode=mode)
    res = edit(table, targets, prof, fit)
    f = _remeasured(res, prof, tmp_path)
    assert abs(f["mu_slope"] - fit["mu_slope"]) < 0.01
    assert abs(f["sigma2"] / targets.sigma2 - 1.0) < 0.02
    assert not any("target not reached" in w for w in res.warnings)
    # The energy is held too, per view and channel, up to 80 deg (beyond, a broad lobe's
    # energy is clipped at the horizon and the edit says so): within the 20 % past which the
    # edit warns (measured in the bench: at most 15 % in warp mode, 12 % in model mode).
    want = target_energy(prof, fit, targets)
    got = np.stack([res.remeasured[c]["alpha"] for c in "rgb"], axis=1)
    below = np.asarray(prof.theta_o) <= np.radians(80.0)
    np.testing.assert_allclose(got[below], want[below], rtol=0.2)
    # Shape. GGX slices are heavy-tailed (excess kurtosis in the hundreds on the near-mirror), and
    # the tails reach the horizon, so widening clips them and the shape moves with it. Narrowing
    # clips nothing: warp keeps the skewness and kurtosis profiles up to what the reciprocal
    # combination mixes in (measured: at most 22 % of the profile's own size up to 60 deg),
    # while model mode puts Gaussians (no excess kurtosis) in their place.
    change = _shape_change(prof, res.remeasured)
    if mode == "warp" and scale < 1.0:
        assert max(change.values()) < 0.25, change
    if mode == "model":
        assert change["kurt_40"] > 0.5 and change["kurt_04"] > 0.5, change


def _round(z, energy_off):
    from addon.core.edit import _Round

    z = np.asarray(z, float)
    return _Round(x=np.zeros(2), y=np.zeros(2), z=z, energy_off=energy_off, ratio=None, out=None, notes=[],
                  profiles=None, fit={})


def test_a_near_miss_keeps_the_round_that_holds_the_energy():
    from addon.core.edit import ROUND_UNITS, _pick_round

    def z_var(off):  # the variance residual, in ROUND_UNITS of log variance, for a relative miss
        return math.log1p(off) / ROUND_UNITS[1]

    # No round meets the tolerances and none has the slope within them: the closest moments
    # (weighted size 3.30) and one a tenth of a unit farther that holds the energy (3 % off, not
    # 24 %). The second is kept; one 2.7 units farther is not, however good its energy.
    closest, tie, far = _round((1.10, -0.08), 0.24), _round((1.12, 0.54), 0.03), _round((2.0, 0.0), 0.0)
    assert closest.size < tie.size < closest.size + 0.5 < far.size
    assert _pick_round([closest, tie, far]) is tie
    assert _pick_round([closest, far]) is closest
    # Slope within tolerance: the variance decides, to within a quarter of its 2 % tolerance.
    a, b, c = _round((0.2, z_var(0.100)), 0.30), _round((0.9, z_var(0.103)), 0.05), _round((0.0, z_var(0.12)), 0.0)
    assert _pick_round([a, b, c]) is b
    assert _pick_round([a, c]) is a
    # Among near ties that all hold the energy (within 20 %), the closest is kept, as among hits.
    held_closest, held_tie = _round((1.10, -0.08), 0.15), _round((1.12, 0.54), 0.01)
    assert _pick_round([held_tie, held_closest]) is held_closest
    # With none held, the better energy is kept.
    dim_closest, dim_tie = _round((1.10, -0.08), 0.6), _round((1.12, 0.54), 0.3)
    assert _pick_round([dim_closest, dim_tie]) is dim_tie
    # A round within the tolerances is kept over any near miss, even if its energy is worse.
    hit = _round((0.5, 0.5), 0.5)
    assert _pick_round([b, hit, tie]) is hit


def test_rounds_go_past_the_budget_only_while_they_close_in():
    from addon.core.edit import CLOSING_GAIN, _closing_in

    def phase(*sizes):  # rounds with only the slope off, so that size = 3 |z_slope|
        return [_round((z / 3.0, 0.0), 0.0) for z in sizes]

    # The last three rounds bettered the earlier best (4.0) by more than CLOSING_GAIN: go on.
    creeping = phase(4.0, 4.6, 3.9, 10.5, 3.4)
    assert [r.size for r in creeping] == pytest.approx([4.0, 4.6, 3.9, 10.5, 3.4])
    assert 3.4 < (1 - CLOSING_GAIN) * 4.0
    assert _closing_in(creeping, creeping)
    # A plateau (an out-of-reach target) stops, and so does a phase too short to judge.
    plateau = phase(13.49, 13.53, 13.54, 13.54, 13.53)
    assert not _closing_in(plateau, plateau)
    assert not _closing_in(creeping, creeping[:3])
    # Once any round meets the tolerances, more rounds would only polish it.
    assert not _closing_in(creeping + [_round((0.5, 0.5), 0.0)], creeping)


def _stub_rounds(monkeypatch, table, prof, fit, remeasured):
    """edit() with the synthesis, re-measurement and fit stubbed: every round re-measures
    ``remeasured``, so only the loop's own rules decide when the rounds stop."""
    import addon.core.edit as E

    made = table.copy()
    monkeypatch.setattr(E, "synthesize", lambda *a, **k: (made, []))
    monkeypatch.setattr(E, "compute_profiles", lambda *a, **k: prof)
    monkeypatch.setattr(E, "fit_material", lambda p: dict(fit, **remeasured))
    return E


@pytest.mark.parametrize("closing", [False, True])
def test_the_rounds_stop_at_the_budget_unless_they_close_in(glossy, monkeypatch, closing):
    table, prof, fit = glossy
    E = _stub_rounds(monkeypatch, table, prof, fit, {"mu_slope": fit["mu_slope"] + 0.2, "sigma2": fit["sigma2"] * 2})
    monkeypatch.setattr(E, "_closing_in", lambda rounds, phase: closing)
    calls = []
    res = E.edit(table, EditTargets(sigma2=fit["sigma2"] * 0.7, mode="model"), prof, fit,
                 progress=lambda done, total: calls.append((done, total)))
    n = E.EXTRA_ROUNDS + 10 if closing else 10
    assert calls == [(k, 10 if k <= 10 else 10 + E.EXTRA_ROUNDS) for k in range(1, n + 1)]
    assert any("target not reached" in w for w in res.warnings)


def test_rounds_that_settle_early_end_the_progress_full(glossy, monkeypatch):
    table, prof, fit = glossy
    target = fit["sigma2"] * 0.7
    E = _stub_rounds(monkeypatch, table, prof, fit, {"sigma2": target})
    calls = []
    res = E.edit(table, EditTargets(sigma2=target, mode="model"), prof, fit,
                 progress=lambda done, total: calls.append((done, total)))
    assert calls == [(1, 10), (1, 1)]
    assert res.achieved_sigma2 == target
    assert not any("target not reached" in w for w in res.warnings)
    with pytest.raises(ValueError, match="max_rounds"):
        E.edit(table, EditTargets(sigma2=target, mode="model"), prof, fit, max_rounds=0)


def test_model_mode_reaches_a_witnessed_target_on_a_broad_lobe(sample_table, tmp_path):
    # The target is what one synthesis re-measured at, so some reciprocal table has it.
    from addon.core.edit import synthesize, view_goals

    table = sample_table("ggx_rough")
    prof = compute_profiles(table)
    fit = fit_material(prof)
    goals = view_goals(prof, fit, "model", fit["mu_slope"] + 0.05, fit["sigma2"] * 1.3) + (1.0,)
    made, _ = synthesize(table, EditTargets(mode="model"), prof, fit, goals)
    witness = fit_material(compute_profiles(made, prof.theta_o, kd=prof.kd, split=prof.split))
    assert -1.0 <= witness["mu_slope"] <= 0.0
    # Start the edit from the slider values, not from the synthesis that made the witness.
    res = edit(table, EditTargets(mu_slope=witness["mu_slope"], sigma2=witness["sigma2"], mode="model"), prof, fit)
    f = _remeasured(res, prof, tmp_path)
    assert abs(f["mu_slope"] - witness["mu_slope"]) < 0.01
    assert abs(f["sigma2"] / witness["sigma2"] - 1.0) < 0.02


def test_warp_mode_reaches_witnessed_targets(sample_table, tmp_path):
    # Targets that one synthesis re-measured at, so some table of this family has them: a
    # near-mirror and a broad lobe, each moved 0.05 away from the normal.
    from addon.core.edit import synthesize, view_goals

    for name, dmu, scale in (("ggx_mirror", -0.05, 1.0), ("ggx_rough", -0.05, 1.0)):
        table = sample_table(name)
        prof = compute_profiles(table)
        fit = fit_material(prof)
        goals = view_goals(prof, fit, "warp", fit["mu_slope"] + dmu, fit["sigma2"] * scale) + (1.0,)
        made, _ = synthesize(table, EditTargets(mode="warp"), prof, fit, goals)
        witness = fit_material(compute_profiles(made, prof.theta_o, kd=prof.kd, split=prof.split))
        assert -1.0 <= witness["mu_slope"] <= 0.0
        res = edit(table, EditTargets(mu_slope=witness["mu_slope"], sigma2=witness["sigma2"], mode="warp"), prof, fit)
        f = _remeasured(res, prof, tmp_path)
        assert abs(f["mu_slope"] - witness["mu_slope"]) < 0.01, name
        assert abs(f["sigma2"] / witness["sigma2"] - 1.0) < 0.02, name


@pytest.mark.parametrize("mode", ["warp", "model"])
def test_an_unreachable_target_is_reported_with_what_was_reached(sample_table, tmp_path, mode):
    # A lobe centred near the horizon cannot hold 1.3x its variance (clipping takes the tails
    # away again): the edit must say so, and the moments it reports must be the written table's.
    # The variance gives way, not the slope: the highlight stays where it was.
    table = sample_table("ggx_rough")
    prof = compute_profiles(table)
    fit = fit_material(prof)
    target = fit["sigma2"] * 1.3
    res = edit(table, EditTargets(sigma2=target, mode=mode), prof, fit)
    f = _remeasured(res, prof, tmp_path)
    assert abs(f["sigma2"] / target - 1.0) >= 0.02
    assert abs(f["mu_slope"] - fit["mu_slope"]) < 0.01
    notes = [w for w in res.warnings if "target not reached" in w]
    assert len(notes) == 1
    assert f"{f['mu_slope']:+.3f}" in notes[0] and f"{f['sigma2']:.4g}" in notes[0]
    assert res.achieved_mu_slope == pytest.approx(f["mu_slope"], abs=1e-9)
    assert res.achieved_sigma2 == pytest.approx(f["sigma2"], rel=1e-9)
