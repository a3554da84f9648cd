"""Stress: the moment sliders at and beyond their limits, and random slider sequences.

The cheap parts (clamping, energy targets, truncated-Gaussian solves) get many random
examples; full edits take seconds each, so a handful run at the extremes and a few random
sequences run end to end (on a 16-view profile grid to keep the suite quick).
"""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _stress import assert_finite_tree, assert_profiles_sane
from addon.core.edit import MIN_SIGMA2, EditTargets, edit, resolve_targets, target_energy
from addon.core.edit.solve import announce
from addon.core.file.merl import MAX_REFLECTANCE, read_merl, write_merl
from addon.core.fits import truncated
from addon.core.fits.curves import LAMBERT_VARIANCE, fit_material
from addon.core.preview.lobe import truncnorm_pdf
from addon.core.profiles.compute import compute_profiles
from addon.core.profiles.integrate import default_views

pytestmark = pytest.mark.stress

H = math.pi / 2


@pytest.fixture(scope="module")
def glossy(sample_table):
    table = sample_table("ggx_glossy")
    prof = compute_profiles(table, default_views(16, 89.0))
    return table, prof, fit_material(prof)


# --- clamping and refusal -------------------------------------------------------------------

# A slider value outside its declared range (core/limits.py: mu~ in [-2, 0], sigma~^2 in
# [1e-8, pi^2/12], energies in [0, 16]) is refused with one line naming the parameter, as the
# command line and the panel refuse it. Inside the declared range, a mean slope beyond this
# material's slider range and a variance below MIN_SIGMA2 are clamped, with a warning.
MU_DECLARED = (-2.0, 0.0)
S2_DECLARED = (1e-8, math.pi**2 / 12)
ENERGY_DECLARED = (0.0, 16.0)
A_DECLARED = (-100.0, 100.0)

# "LO" is the slider's lower end: -1, or the fitted slope where that is below -1 (SPEC §3: the
# ranges hold every fitted value); "LO-" is just below it.
LIMIT_CASES = [
    # (mu, sigma2, expected mu, expected sigma2, clamped?)
    ("LO", LAMBERT_VARIANCE, "LO", LAMBERT_VARIANCE, False),
    (0.0, MIN_SIGMA2, 0.0, MIN_SIGMA2, False),
    ("LO-", 0.1, "LO", 0.1, True),
    (-1.5, 0.1, "LO", 0.1, True),
    (-2.0, 1e-8, "LO", MIN_SIGMA2, True),  # both at their declared lower edges
    (-0.5, 5e-8, -0.5, MIN_SIGMA2, True),
    (-0.0, S2_DECLARED[1], 0.0, LAMBERT_VARIANCE, False),
]


@pytest.mark.parametrize("mu, s2, want_mu, want_s2, clamped", LIMIT_CASES)
def test_sliders_inside_their_declared_ranges_are_clamped_to_the_material_with_a_warning(
    glossy, stress_log, mu, s2, want_mu, want_s2, clamped
):
    _, _, fit = glossy
    lo = min(-1.0, fit["mu_slope"])
    assert lo > MU_DECLARED[0]  # else "LO" would not be a clamp inside the declared range
    sym = {"LO": lo, "LO-": lo - 1e-12 * max(1.0, abs(lo))}
    mu, want_mu = sym.get(mu, mu), sym.get(want_mu, want_mu)
    got_mu, got_s2, warnings = resolve_targets(EditTargets(mu_slope=mu, sigma2=s2), fit)
    assert got_mu == want_mu and got_s2 == pytest.approx(want_s2, rel=1e-12)
    assert bool(warnings) == clamped and all("clamped" in w for w in warnings)
    stress_log.record("slider limits", "clamped" if clamped else "valid", f"mu={mu:g}, sigma2={s2:g}")


OUT_OF_RANGE = [
    ("mu_slope", math.nan),
    ("mu_slope", math.inf),
    ("mu_slope", 1e-12),  # just above 0
    ("mu_slope", -2.0 - 1e-9),
    ("mu_slope", -1e300),
    ("mu_slope", 1e300),
    ("sigma2", -math.inf),
    ("sigma2", math.nan),
    ("sigma2", 0.0),
    ("sigma2", -1.0),
    ("sigma2", 5e-324),
    ("sigma2", LAMBERT_VARIANCE * (1 + 1e-12)),
    ("sigma2", 10.0),
    ("sigma2", 1e300),
    ("strength", -1.0),
    ("strength", math.nan),
    ("strength", 16.000001),
    ("strength", 1e308),
    ("grazing_boost", math.inf),
    ("grazing_boost", 1e308),
    ("grazing_boost", -1e-300),
    ("colour", (1.0, math.nan, 1.0)),
    ("colour", (1.0, -0.1, 1.0)),
    ("colour", (1.0, 1.0, 1e308)),
    ("correlation_a", math.nan),
    ("correlation_a", 1e308),
]


@pytest.mark.parametrize("field, value", OUT_OF_RANGE)
def test_slider_values_outside_their_declared_ranges_are_refused_naming_the_parameter(glossy, stress_log, field, value):
    table, prof, fit = glossy
    targets = dataclasses.replace(EditTargets(), **{field: value})
    # every public entry point of the edit refuses it, before any work, naming the parameter
    for call in (
        lambda: resolve_targets(targets, fit),
        lambda: announce(prof, fit, targets),
        lambda: edit(table, targets, prof, fit),
        lambda: target_energy(prof, fit, targets),
    ):
        with pytest.raises(ValueError) as info:
            call()
        msg = str(info.value)
        assert len(msg.splitlines()) == 1 and msg.startswith(field + ":"), msg
    stress_log.record("slider limits", "error", f"{field}={value!r}")


@pytest.mark.parametrize(
    "field, value, fragment",
    [("colour", (1.0, 1.0), "colour"), ("mode", "bogus", "mode"), ("lock", True, "correlation_a")],
)
def test_impossible_slider_settings_are_clear_errors(glossy, stress_log, field, value, fragment):
    _, _, fit = glossy
    with pytest.raises(ValueError) as info:
        resolve_targets(dataclasses.replace(EditTargets(), **{field: value}), fit)
    assert str(info.value).startswith(fragment + ":"), str(info.value)
    stress_log.record("slider limits", "error", f"{field}={value!r}")


FINITE = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)
ANY = st.one_of(FINITE, st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([-1.0, 0.0, -0.0, 1e-300]))
STEP = st.one_of(
    st.tuples(st.just("mu_slope"), st.one_of(ANY, st.floats(-2.2, 0.2))),
    st.tuples(st.just("sigma2"), st.one_of(ANY, st.floats(-0.1, 1.0))),
    st.tuples(st.just("strength"), st.one_of(ANY, st.floats(0.0, 20.0))),
    st.tuples(st.just("grazing_boost"), st.one_of(ANY, st.floats(0.0, 20.0))),
    st.tuples(st.just("colour"), st.tuples(st.floats(0.0, 2.0), ANY, st.floats(0.0, 2.0))),
    st.tuples(st.just("mode"), st.sampled_from(["warp", "model"])),
    st.tuples(st.just("lock"), st.booleans()),
    st.tuples(st.just("correlation_a"), st.one_of(st.none(), ANY, st.floats(-120.0, 120.0))),
)


def _inside(value, bounds):
    return math.isfinite(value) and bounds[0] <= value <= bounds[1]


def _out_of_range(t):
    """The fields of ``t`` outside their declared ranges (written out here, not read from the code)."""
    bad = []
    if not _inside(t.strength, ENERGY_DECLARED):
        bad.append("strength")
    if not all(_inside(c, ENERGY_DECLARED) for c in t.colour):
        bad.append("colour")
    if not _inside(t.grazing_boost, ENERGY_DECLARED):
        bad.append("grazing_boost")
    for name, bounds in (("mu_slope", MU_DECLARED), ("sigma2", S2_DECLARED), ("correlation_a", A_DECLARED)):
        v = getattr(t, name)
        if v is not None and not _inside(v, bounds):
            bad.append(name)
    return bad


@settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(steps=st.lists(STEP, min_size=1, max_size=12))
def test_random_slider_sequences_always_resolve_to_valid_targets_or_a_clear_error(glossy, stress_log, steps):
    _, prof, fit = glossy
    t = EditTargets()
    for field, value in steps:
        t = dataclasses.replace(t, **{field: value})
        bad = _out_of_range(t)
        try:
            mu, s2, warnings = resolve_targets(t, fit)
        except ValueError as exc:
            # Refused only for a reason the message states: a value outside its declared
            # range (the message names it), or a lock without a fitted quadratic.
            msg = str(exc)
            assert len(msg.splitlines()) == 1, msg
            if bad:
                assert msg.split(":", 1)[0] in bad, (msg, bad)
            else:
                assert t.lock and t.correlation_a is None and msg.startswith("correlation_a:"), msg
            stress_log.record("random slider steps (clamping, 300 sequences)", "error")
            t = EditTargets()  # the UI keeps the last good state; start over
            continue
        assert not bad, (bad, t)  # an out-of-range value is never clamped in silence
        assert math.isfinite(mu) and math.isfinite(s2)
        assert MIN_SIGMA2 <= s2 <= LAMBERT_VARIANCE
        if t.mu_slope is not None:
            lo, hi = min(-1.0, fit["mu_slope"]), max(0.0, fit["mu_slope"])  # the range holds the fit
            assert lo <= mu <= hi
            assert mu == min(max(t.mu_slope, lo), hi)
        if t.sigma2 is not None and not t.lock:
            assert s2 == pytest.approx(min(max(t.sigma2, MIN_SIGMA2), LAMBERT_VARIANCE), rel=1e-12)
        energy = target_energy(prof, fit, t)
        assert np.all(np.isfinite(energy)) and np.all(energy >= 0)
        stress_log.record("random slider steps (clamping, 300 sequences)", "clamped" if warnings else "valid")


@settings(
    max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(mean=st.floats(-H, H), var=st.floats(1e-12, LAMBERT_VARIANCE))
def test_truncated_gaussian_solve_is_finite_and_exact_where_it_says_so(stress_log, mean, var):
    m, s, used = truncated.solve(np.array([mean]), np.array([var]))
    assert np.isfinite(m).all() and np.isfinite(s).all() and s[0] > 0
    mt, vt = truncated.moments(m, s)
    assert np.isfinite(mt).all() and np.isfinite(vt).all() and vt[0] > 0
    # Reached: nothing capped, and the widths' bounds did not stop it.
    ok = used[0] >= max(var, 1e-14) and abs(mt[0] - mean) < 1e-6 and abs(vt[0] / used[0] - 1) < 1e-4
    if ok:
        assert mt[0] == pytest.approx(mean, abs=1e-6) and vt[0] == pytest.approx(var, rel=1e-4)
    x = np.linspace(-H, H, 257)
    g = truncnorm_pdf(x, m[0], s[0])
    assert np.isfinite(g).all() and (g >= 0).all()
    stress_log.record("truncated-Gaussian solve (random targets)", "valid" if ok else "clamped")


# --- full edits -----------------------------------------------------------------------------


def _check_result(res, table, tmp_path, name):
    out = res.table
    assert out.rho.shape == table.rho.shape
    np.testing.assert_array_equal(out.valid, table.valid)  # missing stays missing
    assert np.isfinite(out.rho).all() and (out.rho >= 0).all()
    assert out.rho.max() <= MAX_REFLECTANCE
    assert np.isfinite(res.max_albedo).all()
    for v in (res.achieved_mu_slope, res.achieved_sigma2):
        assert v is None or math.isfinite(v)
    if res.profiles is not None:
        assert_profiles_sane(res.profiles)
        assert_finite_tree(res.profiles.to_json())
    path = tmp_path / f"{name}.binary"
    write_merl(out, path)
    # rho / scale * scale may move the last bit: the stored format is unscaled.
    np.testing.assert_allclose(read_merl(path).rho, out.rho, rtol=1e-15, atol=0)


EXTREMES = [
    # sigma~^2 = 1e-8, the declared range's lower edge, is clamped to MIN_SIGMA2 (a needle)
    ("mirror", EditTargets(mu_slope=-1.0, sigma2=1e-8)),
    ("lambertian", EditTargets(mu_slope=0.0, sigma2=LAMBERT_VARIANCE)),
    ("beyond, model", EditTargets(mu_slope=-2.0, sigma2=LAMBERT_VARIANCE, mode="model")),
    ("needle at the normal, model", EditTargets(mu_slope=0.0, sigma2=1e-8, mode="model")),
    ("black", EditTargets(strength=0.0)),
    ("near-black channel", EditTargets(colour=(1.0, 1e-30, 0.0))),
]
_RESULTS = {}


def _edit(glossy, name, targets):
    """Edits take seconds: each extreme runs once per session and its outcome is shared."""
    if name not in _RESULTS:
        table, prof, fit = glossy
        try:
            _RESULTS[name] = edit(table, targets, prof, fit)
        except ValueError as exc:
            _RESULTS[name] = exc
    return _RESULTS[name]


@pytest.mark.parametrize("name, targets", EXTREMES, ids=[e[0] for e in EXTREMES])
def test_edits_at_the_extremes_give_valid_tables_or_clear_errors(glossy, stress_log, tmp_path, name, targets):
    table, prof, fit = glossy
    before = table.rho.copy()
    res = _edit(glossy, name, targets)
    np.testing.assert_array_equal(table.rho, before)  # the input is never modified
    if isinstance(res, ValueError):
        # A needle off the mirror is narrower than the table's cells there: nothing of it
        # survives tabulation, and the edit says so instead of returning a black table.
        assert table.name in str(res) and "no specular energy" in str(res)
        stress_log.record("full edits at the slider limits", "error", f"{name}: {res}")
        return
    _check_result(res, table, tmp_path, "".join(c if c.isalnum() else "_" for c in name))
    clamped = any("clamped" in w for w in res.warnings)
    if targets.sigma2 is not None and not MIN_SIGMA2 <= targets.sigma2 <= LAMBERT_VARIANCE:
        assert clamped
    if targets.mu_slope is not None and targets.mu_slope < min(-1.0, fit["mu_slope"]):
        assert clamped
    if targets.strength == 0.0:
        kd = prof.kd
        np.testing.assert_allclose(res.table.rho, np.where(table.valid, np.minimum(table.rho, kd[:, None]), 0.0))
    stress_log.record("full edits at the slider limits", "clamped" if res.warnings else "valid", name)


def test_a_needle_edit_keeps_the_energy_or_says_it_cannot(glossy):
    _, prof, _ = glossy
    res = _edit(glossy, "mirror", dict(EXTREMES)["mirror"])
    want = prof["avg"]["alpha"]
    got = res.profiles["avg"]["alpha"]
    lost = np.abs(got / want - 1.0) > 0.2
    assert not lost.any() or any("energy" in w for w in res.warnings), (np.degrees(prof.theta_o[lost]), got[lost])


@settings(
    max_examples=3,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    steps=st.lists(
        st.one_of(
            # inside the declared ranges: outside, an edit is refused before any work (above)
            st.tuples(st.just("mu_slope"), st.floats(*MU_DECLARED)),
            st.tuples(st.just("sigma2"), st.floats(*S2_DECLARED)),
            st.tuples(st.just("strength"), st.floats(0.0, 3.0)),
            st.tuples(st.just("mode"), st.sampled_from(["warp", "model"])),
        ),
        min_size=2,
        max_size=6,
    )
)
def test_random_slider_sequences_end_to_end(glossy, stress_log, tmp_path_factory, steps):
    table, prof, fit = glossy
    t = EditTargets()
    for field, value in steps:
        t = dataclasses.replace(t, **{field: value})
    case = ", ".join(f"{f}={v:.3g}" if isinstance(v, float) else f"{f}={v}" for f, v in steps)
    try:
        res = edit(table, t, prof, fit)
    except ValueError as exc:  # must be the documented refusal, naming the material
        assert table.name in str(exc)
        stress_log.record("random slider sequences (full edit)", "error", f"{case} -> {exc}")
        return
    _check_result(res, table, tmp_path_factory.mktemp("seq"), "seq")
    stress_log.record("random slider sequences (full edit)", "clamped" if res.warnings else "valid", case)


def test_edit_of_a_material_without_specular_lobe_is_a_clear_error(sample_table, stress_log):
    lam = sample_table("lambertian")
    prof = compute_profiles(lam, default_views(16, 89.0))
    with pytest.raises(ValueError, match="no specular lobe"):
        edit(lam, EditTargets(mu_slope=-0.5), prof)
    stress_log.record("full edits at the slider limits", "error", "lambertian input (nothing to edit)")
