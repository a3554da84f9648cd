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
from addon.core import truncated
from addon.core.edit import MIN_SIGMA2, EditTargets, edit, resolve_targets, target_energy
from addon.core.fits import LAMBERT_VARIANCE, fit_material
from addon.core.integrate import default_views
from addon.core.merl import MAX_REFLECTANCE, read_merl, write_merl
from addon.core.profiles import compute_profiles
from addon.core.render.lobe import truncnorm_pdf

pytestmark = pytest.mark.stress

H = math.pi / 2


@pytest.fixture(scope="module")
def glossy(sample_table):
    table = sample_table("ggx_glossy")
    prof = compute_profiles(table, default_views(16, 89.0))
    return table, prof, fit_material(prof)


# --- clamping ------------------------------------------------------------------------------

# "LO" is the slider's lower end: -1, or the fitted slope where that is below -1 (SPEC §3: the
# ranges hold every fitted value); "LO-" is just below it.
LIMIT_CASES = [
    # (mu, sigma2, expected mu, expected sigma2, clamped?)
    ("LO", LAMBERT_VARIANCE, "LO", LAMBERT_VARIANCE, False),
    (0.0, MIN_SIGMA2, 0.0, MIN_SIGMA2, False),
    ("LO-", 0.1, "LO", 0.1, True),
    (1e-12, 0.1, 0.0, 0.1, True),
    (-1.5, 0.0, "LO", MIN_SIGMA2, True),
    (0.5, -1.0, 0.0, MIN_SIGMA2, True),
    (-1e300, 1e300, "LO", LAMBERT_VARIANCE, True),
    (1e300, 5e-324, 0.0, MIN_SIGMA2, True),
    (-0.5, LAMBERT_VARIANCE * (1 + 1e-12), -0.5, LAMBERT_VARIANCE, True),
    (-0.5, 10.0, -0.5, LAMBERT_VARIANCE, True),
]


@pytest.mark.parametrize("mu, s2, want_mu, want_s2, clamped", LIMIT_CASES)
def test_sliders_at_and_beyond_their_limits_are_clamped_with_a_warning(
    glossy, stress_log, mu, s2, want_mu, want_s2, clamped
):
    _, _, fit = glossy
    lo = min(-1.0, fit["mu_slope"])
    sym = {"LO": lo, "LO-": lo - 1e-12 * max(1.0, abs(lo))}
    mu, want_mu = sym.get(mu, mu), sym.get(want_mu, want_mu)
    got_mu, got_s2, warnings = resolve_targets(EditTargets(mu_slope=mu, sigma2=s2), fit)
    assert got_mu == want_mu and got_s2 == pytest.approx(want_s2, rel=1e-12)
    assert bool(warnings) == clamped and all("clamped" in w for w in warnings)
    stress_log.record("slider limits", "clamped" if clamped else "valid", f"mu={mu:g}, sigma2={s2:g}")


@pytest.mark.parametrize(
    "field, value",
    [
        ("mu_slope", math.nan),
        ("mu_slope", math.inf),
        ("sigma2", -math.inf),
        ("sigma2", math.nan),
        ("strength", -1.0),
        ("strength", math.nan),
        ("grazing_boost", math.inf),
        ("colour", (1.0, math.nan, 1.0)),
        ("colour", (1.0, -0.1, 1.0)),
        ("colour", (1.0, 1.0)),
        ("mode", "bogus"),
        ("lock", True),
    ],
)
def test_impossible_slider_values_are_clear_errors(glossy, stress_log, field, value):
    _, _, fit = glossy
    with pytest.raises(ValueError) as info:
        resolve_targets(dataclasses.replace(EditTargets(), **{field: value}), fit)
    assert str(info.value)  # a message the UI can show
    stress_log.record("slider limits", "error", f"{field}={value!r}")


FINITE = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)
ANY = st.one_of(FINITE, st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([-1.0, 0.0, -0.0, 1e-300]))
STEP = st.one_of(
    st.tuples(st.just("mu_slope"), st.one_of(ANY, st.floats(-1.2, 0.2))),
    st.tuples(st.just("sigma2"), st.one_of(ANY, st.floats(-0.1, 1.0))),
    st.tuples(st.just("strength"), st.one_of(ANY, st.floats(0.0, 4.0))),
    st.tuples(st.just("grazing_boost"), st.one_of(ANY, st.floats(0.0, 4.0))),
    st.tuples(st.just("colour"), st.tuples(st.floats(0.0, 2.0), ANY, st.floats(0.0, 2.0))),
    st.tuples(st.just("mode"), st.sampled_from(["warp", "model"])),
    st.tuples(st.just("lock"), st.booleans()),
    st.tuples(st.just("correlation_a"), st.one_of(st.none(), ANY)),
)


def _valid_step(field, value):
    """What a UI with property limits would accept: finite numbers, non-negative energies."""
    if field in ("mu_slope", "sigma2", "correlation_a"):
        return value is None or math.isfinite(value)
    if field in ("strength", "grazing_boost"):
        return math.isfinite(value) and value >= 0
    if field == "colour":
        return all(math.isfinite(c) and c >= 0 for c in value)
    return True


@settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(steps=st.lists(STEP, min_size=1, max_size=12))
def test_random_slider_sequences_always_resolve_to_valid_targets_or_a_clear_error(glossy, stress_log, steps):
    _, prof, fit = glossy
    t = EditTargets()
    for field, value in steps:
        t = dataclasses.replace(t, **{field: value})
        try:
            mu, s2, warnings = resolve_targets(t, fit)
        except ValueError as exc:
            # Refused only for a reason the message states: a value no slider can hold, a lock
            # without a fitted quadratic, or a quadratic that overflows.
            fields = ("mu_slope", "sigma2", "strength", "grazing_boost", "colour", "correlation_a")
            impossible = not all(_valid_step(f, getattr(t, f)) for f in fields)
            assert impossible or (t.lock and t.correlation_a is None) or "finite" in str(exc), str(exc)
            stress_log.record("random slider steps (clamping, 300 sequences)", "error")
            t = EditTargets()  # the UI keeps the last good state; start over
            continue
        assert math.isfinite(mu) and math.isfinite(s2)
        assert MIN_SIGMA2 <= s2 <= LAMBERT_VARIANCE
        if t.mu_slope is not None:
            lo, hi = min(-1.0, fit["mu_slope"]), max(0.0, fit["mu_slope"])  # the range holds the fit
            assert lo <= mu <= hi
            assert mu == min(max(t.mu_slope, lo), hi)
        if t.sigma2 is not None and not t.lock:
            assert s2 == pytest.approx(min(max(t.sigma2, MIN_SIGMA2), LAMBERT_VARIANCE), rel=1e-12)
        energy = target_energy(prof, fit, t)
        scale = t.strength * max(t.colour) * max(t.grazing_boost, 1.0)
        if scale < 1e300:
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
    ("mirror", EditTargets(mu_slope=-1.0, sigma2=0.0)),
    ("lambertian", EditTargets(mu_slope=0.0, sigma2=LAMBERT_VARIANCE)),
    ("beyond, model", EditTargets(mu_slope=-1.5, sigma2=100.0, mode="model")),
    ("needle at the normal, model", EditTargets(mu_slope=0.0, sigma2=1e-300, mode="model")),
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
            st.tuples(st.just("mu_slope"), st.floats(-1.3, 0.3)),
            st.tuples(st.just("sigma2"), st.floats(-0.1, 1.2)),
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
