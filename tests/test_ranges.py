"""One contract for ranges (issue 38): a public engine function refuses a size, a count or a
slider value outside its declared range (``core.limits.RANGES``, the one table the command line
and the panel read too) with a ValueError of one line naming the argument and the range.

The public functions are found, not listed: everything an engine package exports (its
``__all__``: functions, classes with their public methods, the functions of an exported module)
whose signature takes a number (an int or float default, or an int or float annotation). Each
must have a call in ``_calls``, which is made with 1e308, NaN, -1 and 0 for every numeric
argument (each value outside the argument's declared range must be refused), or an exemption
in ``EXEMPT`` with its reason. A new public function taking a number fails the test until it is
one or the other. (The engine's ground, ``limits``, ``geometry`` and ``microsurface``, holds the
bounds themselves and closed forms on arrays: no size, count or slider.)"""

import importlib
import inspect
import math
import numbers
import os
import pkgutil
import re
import types

import numpy as np
import pytest

import addon.core as core
from addon.core.limits import RANGES

HOSTILE = (1e308, math.nan, -1, 0)

EXEMPT = {
    # Records the engine returns: their numbers are what it computed, not what a caller asks.
    "addon.core.edit.reach.ReachableRegion": "a result of reachable_region",
    "addon.core.edit.solve.EditResult": "a result of edit",
    "addon.core.edit.targets.ViewTargets": "a result of view_targets",
    "addon.core.material.lobes.LobeFit": "a result of fit_lobes",
    "addon.core.material.principled.PrincipledFit": "a result of fit_principled",
    "addon.core.preview.scene.Layout": "a result of sphere_layout (which checks its numbers)",
    "addon.core.profiles.compute.Profiles": "a result of compute_profiles",
    # Values the engine derives, not sliders.
    "addon.core.preview.lobe.MomentParams": "the model's fitted parameters (from_fit, checked finite, sigma2 in"
    " (0, pi^2/12]); the sliders reach it through edited(), called below",
    "addon.core.edit.targets.view_targets": "the (mu, sigma2) resolve_targets made of the sliders (checked"
    " there and by edit, below): the material's own fit where a slider is left alone, which may lie outside"
    " the sliders' range (a broad measured lobe's sigma2 near 1)",
}

_NUMBER = re.compile(r"\b(int|float)\b")


def _public_callables():
    """(qualified name, callable) of everything the engine's packages export."""
    packages = [m.name for m in pkgutil.iter_modules(core.__path__) if m.ispkg]
    assert len(packages) >= 6
    for name in packages:
        package = importlib.import_module(f"addon.core.{name}")
        assert hasattr(package, "__all__"), f"addon.core.{name} exports nothing: its __all__ is its public face"
        for attr in package.__all__:
            obj = getattr(package, attr)
            if isinstance(obj, types.ModuleType):
                for a, f in vars(obj).items():
                    if not a.startswith("_") and inspect.isfunction(f) and f.__module__ == obj.__name__:
                        yield f"{obj.__name__}.{a}", f
            elif inspect.isclass(obj):
                yield f"{obj.__module__}.{obj.__qualname__}", obj
                for a, f in vars(obj).items():
                    f = f.__func__ if isinstance(f, (classmethod, staticmethod)) else f
                    if not a.startswith("_") and inspect.isfunction(f):
                        yield f"{obj.__module__}.{obj.__qualname__}.{a}", f
            elif callable(obj):
                yield f"{obj.__module__}.{obj.__qualname__}", obj


def _numeric_parameters(fn):
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):  # an exception class or a builtin
        return []
    out = []
    for p in params:
        if p.name in ("self", "cls") or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            continue
        default_is_number = isinstance(p.default, numbers.Real) and not isinstance(p.default, bool)
        annotation = p.annotation if isinstance(p.annotation, str) else getattr(p.annotation, "__name__", "")
        if default_is_number or (p.annotation is not p.empty and _NUMBER.search(str(annotation))):
            out.append(p.name)
    return out


def _discovered():
    return {q: _numeric_parameters(f) for q, f in _public_callables() if _numeric_parameters(f)}


@pytest.fixture(scope="module")
def ctx(sample_table):
    from addon.core.fits import fit_material
    from addon.core.preview import Environment, ModelBRDF, MomentParams, sphere_layout
    from addon.core.profiles import compute_profiles, default_views

    table = sample_table("ggx_glossy")
    prof = compute_profiles(table, default_views(4, 80.0))
    fit = fit_material(prof)
    params = MomentParams.from_fit(fit, prof.kd)
    return types.SimpleNamespace(
        table=table,
        prof=prof,
        fit=fit,
        params=params,
        brdf=ModelBRDF(params),
        env=Environment.constant((1.0, 1.0, 1.0)),
        layout=sphere_layout(16, 16, 1),
    )


def _calls(c):
    """qualified name -> (call(**arguments), {argument: its RANGES entry, or (entry, how the
    value is passed)}): one call per public function that takes a number, valid but for the
    argument under test."""
    from addon.core import edit as E
    from addon.core import fits as F
    from addon.core import material as M
    from addon.core import preview as P
    from addon.core import profiles as R

    one = np.array([[0.0, 0.0, 1.0]])
    sliders = {k: k for k in ("strength", "grazing_boost", "mu_slope", "sigma2")}
    sliders["colour"] = ("colour", lambda v: (1.0, v, 1.0))
    return {
        # profiles
        "addon.core.profiles.integrate.default_views": (
            R.default_views,
            {"count": "elevations", "max_deg": "max_elevation"},
        ),
        "addon.core.profiles.integrate.directional_albedo": (
            lambda **k: R.directional_albedo(c.table, c.prof.theta_o, **k),
            {"stride": "stride"},
        ),
        "addon.core.profiles.compute.compute_profiles": (
            lambda **k: R.compute_profiles(c.table, c.prof.theta_o, **k),
            {"max_order": "max_order"},
        ),
        "addon.core.profiles.compute.function_profiles": (
            lambda **k: R.function_profiles(lambda t, p, o: np.ones((1, np.size(t))), [0.5], **k),
            {"max_order": "max_order"},
        ),
        "addon.core.profiles.compute.monte_carlo_profiles": (
            lambda **k: R.monte_carlo_profiles(
                lambda t, p, o: np.ones((1, np.size(t))), [0.5], **{"n_samples": 64, **k}
            ),
            {"n_samples": "mc_samples", "seed": "seed", "max_order": "max_order"},
        ),
        "addon.core.profiles.quadrature.RuleParams": (
            R.RuleParams,
            {
                "n_phi": "rule_lines",
                "n_panels": "rule_lines",
                "n_panels_phi": "rule_lines",
                "n_gauss": "gauss_nodes",
                "n_gauss_far": "gauss_nodes",
                "n_probe": "rule_probes",
                "fade_from": "fade_angle",
                "fade_to": "fade_angle",
            },
        ),
        # fits
        "addon.core.fits.truncated.solve": (lambda **k: F.truncated.solve(0.1, 0.05, **k), {"iters": "iterations"}),
        # edit: the sliders at its entry point, as the command line and the panel hand them over
        "addon.core.edit.targets.EditTargets": (
            lambda **k: E.edit(c.table, E.EditTargets(**k), c.prof, c.fit, remeasure=False),
            {**sliders, "correlation_a": "correlation_a", "roughness": "roughness"},
        ),
        "addon.core.edit.solve.scale_to_albedo": (lambda **k: E.scale_to_albedo(None, **k), {"limit": "albedo_limit"}),
        "addon.core.edit.reach.reachable_region": (
            lambda **k: E.reachable_region(c.prof, c.fit, **k),
            {"n_sigma": "region_grid", "n_mu": "region_grid"},
        ),
        # the artist's material
        "addon.core.material.lobes.fit_lobes": (
            lambda **k: M.fit_lobes(c.table, **k),
            {"n_lobes": "lobes", "n_views": "lookup_texels", "diffuse_quantile": "share"},
        ),
        "addon.core.material.lobes.near_mirror_floor": (
            lambda **k: M.near_mirror_floor(c.table, **k),
            {"theta_h_max_deg": "near_mirror_deg"},
        ),
        # the preview's numbers
        "addon.core.preview.cache.BakeCache": (
            P.BakeCache,
            {"max_items": "bake_cache_items", "max_files": "bake_cache_files", "max_bytes": "bake_cache_bytes"},
        ),
        "addon.core.preview.cache.BakeCache.get": (
            lambda **k: P.BakeCache().get(c.brdf, c.env, **{"diameter": 8, **k}),
            {"diameter": "diameter", "lobe_samples": "bake_samples", "seed": "seed"},
        ),
        "addon.core.preview.cache.bake_key": (
            lambda **k: P.bake_key(c.brdf, c.env, **{"diameter": 8, "lobe_samples": 4, **k}),
            {"diameter": "diameter", "lobe_samples": "bake_samples", "seed": "seed"},
        ),
        "addon.core.preview.envmap.Environment.constant": (
            lambda **k: P.Environment.constant((1.0, 1.0, 1.0), **k),
            {"width": "image_side", "height": "image_side"},
        ),
        "addon.core.preview.envmap.Environment.from_function": (
            lambda **k: P.Environment.from_function(lambda d: d * 0.0 + 1.0, **k),
            {"width": "image_side", "height": "image_side"},
        ),
        "addon.core.preview.envmap.Environment.split": (lambda **k: c.env.split(**k), {"contrast": "contrast"}),
        "addon.core.preview.envmap.Environment.irradiance": (
            lambda **k: c.env.irradiance(one, **k),
            {"chunk": "chunk"},
        ),
        "addon.core.preview.envmap.Environment.irradiance_map": (c.env.irradiance_map, {"diameter": "diameter"}),
        "addon.core.preview.estimators.bake_sphere": (
            lambda **k: P.bake_sphere(c.brdf, c.env, **{"diameter": 8, "lobe_samples": 4, **k}),
            {
                "diameter": "diameter",
                "lobe_samples": "bake_samples",
                "seed": "seed",
                "light_samples": "light_samples",
                "cosine_share": "share",
            },
        ),
        "addon.core.preview.estimators.reference_sphere": (
            lambda **k: P.reference_sphere(c.brdf, c.env, **{"diameter": 8, "spp": 4, **k}),
            {
                "diameter": "diameter",
                "spp": "spp",
                "seed": "seed",
                "diffuse_grid": "diffuse_grid",
                "shares": ("share", lambda v: (0.5, v, 0.5)),
            },
        ),
        "addon.core.preview.estimators.render_reference": (
            lambda **k: P.render_reference(c.layout, [c.brdf], c.env, **{"spp": 4, **k}),
            {"spp": "spp", "seed": "seed"},
        ),
        "addon.core.preview.estimators.render_baked": (
            lambda **k: P.render_baked(c.layout, [c.brdf], c.env, **{"lobe_samples": 4, **k}),
            {"lobe_samples": "bake_samples", "seed": "seed", "light_samples": "light_samples"},
        ),
        "addon.core.preview.lobe.HalfVectorSampler": (
            lambda **k: P.HalfVectorSampler(lambda t, p, o: np.ones(np.shape(t)), **k),
            {"n_rows": "sampler_rows", "n_rings": "sampler_rings", "sub": ("sampler_sub", lambda v: (v, 4))},
        ),
        "addon.core.preview.lobe.MomentParams.edited": (c.params.edited, sliders),
        "addon.core.preview.lobe.truncated_params": (
            lambda **k: P.truncated_params(0.1, 0.05, **k),
            {"iters": "iterations"},
        ),
        "addon.core.preview.estimators.lit_pixel_errors": (
            lambda **k: P.lit_pixel_errors(np.ones((4, 4, 3)), np.ones((4, 4, 3)), np.ones((4, 4), bool), **k),
            {"share": "share"},
        ),
        "addon.core.preview.scene.sphere_layout": (
            lambda **k: P.sphere_layout(**{"width": 64, **k}),
            {"width": "image_side", "height": "image_side", "count": "spheres", "fill": "fill"},
        ),
    }


def _inside(rng, v):
    if not math.isfinite(v) or (rng.integer and v != int(v)):
        return False
    return rng.low <= v <= rng.high


def test_every_public_function_taking_a_number_has_a_call_or_a_reason(ctx):
    """The registry below and the code agree: each numeric argument found is either called with
    hostile values or its function is exempt, and nothing in the registry is stale."""
    calls = _calls(ctx)
    found = _discovered()
    assert len(found) >= 30  # the scan saw the engine's faces
    missing = {
        q: [p for p in params if p not in calls.get(q, (None, {}))[1]] for q, params in found.items() if q not in EXEMPT
    }
    assert {q: p for q, p in missing.items() if p} == {}, "check these against core.limits, or exempt them"
    assert [q for q in calls if q not in found] == [] and [q for q in EXEMPT if q not in found] == []
    for q, (_, args) in calls.items():
        for arg in args.values():
            assert (arg if isinstance(arg, str) else arg[0]) in RANGES, q


def test_the_engine_refuses_out_of_range_numbers_at_every_public_function(ctx):
    """1e308, NaN, -1 and 0 for every numeric argument: each value outside the declared range is
    refused before any work, one line naming the argument and the range (as the command line
    says it: ``between LOW and HIGH``)."""
    refused = 0
    for q, (call, args) in _calls(ctx).items():
        for name, spec in args.items():
            entry, wrap = (spec, None) if isinstance(spec, str) else spec
            rng = RANGES[entry]
            for v in HOSTILE:
                if _inside(rng, v):
                    continue  # in range: the function's ordinary work, not this test's
                with pytest.raises(ValueError) as err:
                    call(**{name: wrap(v) if wrap else v})
                msg = str(err.value)
                assert len(msg.splitlines()) == 1 and msg.startswith(name), (q, name, v, msg)
                assert rng.describe() in msg, (q, name, v, msg)
                refused += 1
    assert refused >= 150


def test_the_discovery_sees_a_new_unchecked_function(monkeypatch):
    """The rule itself: a public function with a count that no call covers is reported."""
    import addon.core.fits as fits

    def fit_more(prof, rounds: int = 3):
        return prof

    fit_more.__module__, fit_more.__qualname__ = "addon.core.fits.curves", "fit_more"
    monkeypatch.setattr(fits, "fit_more", fit_more, raising=False)
    monkeypatch.setattr(fits, "__all__", [*fits.__all__, "fit_more"])
    assert _discovered()["addon.core.fits.curves.fit_more"] == ["rounds"]


def test_the_ranges_at_the_engine_are_the_command_lines(tmp_path):
    """The same number is refused in the same words by the engine and the command line: the
    engine names its argument where the command line names its flag."""
    from _stress import run_cli
    from addon.core.edit import EditTargets, edit

    with pytest.raises(ValueError) as err:
        edit(None, EditTargets(grazing_boost=1e308))
    res = run_cli(
        "edit", os.path.join("samples", "none.binary"), "--out", tmp_path / "o.binary", "--grazing-boost", "1e308"
    )
    assert res.returncode == 2
    engine = str(err.value).split(": ", 1)[1]
    assert engine.split(", got")[0] in res.stderr, (engine, res.stderr)
