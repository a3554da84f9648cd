"""The check that Cycles renders a stretched lobe of ``core.material.lobes`` as the fit models it: one GGX
lobe (roughness 0.3, white) stretched across the plane of incidence (aspect 3 past the first
texel; and, as broad edits need, in it: aspect 1/3; and the other kinds: Beckmann, Fresnel, Velvet,
rough Diffuse), put into a material by the add-on's ``apply_lobes``, on a sphere under Blender's studio
HDRI, against a converged numpy render of the model itself (``lobes_brdf``: a MERL table cannot
hold it, its axes follow the view and a table is reciprocal), of the same lobe stretched in the
plane, and of the round lobe. Run by the bpy-module tests and, in Debian's 3.4, by
tests/blender/stretched.py."""

import numpy as np

ROUGHNESS, ASPECT, SIZE, SAMPLES = 0.3, 3.0, 64, 1024


def _kinds_case(L, shadowing):
    """A Beckmann lobe (roughness 0.3, weight 0.3) and a GGX lobe times the Principled's Fresnel
    factor (roughness 0.2, weight 1, the Mix Shader's most), no diffuse; against the same with
    the Beckmann lobe drawn as GGX, and with the Fresnel lobe's factor left out (weight 0.1)."""
    n = L.N_VIEWS
    w = np.zeros((3, n, 3))
    w[1], w[2] = 0.3, 1.0
    rough = (0.3, 0.2)
    plain = w.copy()
    plain[2] = 0.1
    return L.LobeFit(rough, w, shadowing, 0.0, 0.0, None, (L.BECKMANN, L.FRESNEL)), {
        "GGX for Beckmann": L.LobeFit(rough, w, shadowing, 0.0, 0.0, None, (L.GGX, L.FRESNEL)),
        "no Fresnel": L.LobeFit(rough, plain, shadowing, 0.0, 0.0, None, (L.BECKMANN, L.GGX)),
    }


def _velvet_case(L, shadowing):
    """One Velvet (sigma 0.35, weight 0.8) over a dim diffuse (0.1); against the same at sigma 1
    and with a GGX lobe of roughness 0.35 in its place."""
    w = np.zeros((2, L.N_VIEWS, 3))
    w[0], w[1] = 0.1, 0.8
    return L.LobeFit((0.35,), w, shadowing, 0.0, 0.0, None, (L.VELVET,)), {
        "sigma 1": L.LobeFit((1.0,), w, shadowing, 0.0, 0.0, None, (L.VELVET,)),
        "GGX": L.LobeFit((0.35,), w, shadowing, 0.0, 0.0, None, (L.GGX,)),
    }


def _rough_case(L, shadowing):
    """A rough diffuse (white Diffuse BSDF at roughness 1, weight 0.8) over a dim diffuse (0.1);
    against a Lambert of the same albedo at normal view, and against the other Blenders' rough
    diffuse (4.x's multiple scattering in 3.x, none in 4.x)."""
    w = np.zeros((2, L.N_VIEWS, 3))
    w[0], w[1] = 0.1, 0.8
    other = "separable" if shadowing == "correlated" else "correlated"
    lambert = np.zeros((1, L.N_VIEWS, 3))
    lambert[0] = (
        0.1 + 0.8 * float(L.rough_diffuse(np.array([[0.0, 0.0, 1.0]]), np.array([0.0, 0.0, 1.0]), shadowing)[0]) * np.pi
    )
    return L.LobeFit((1.0,), w, shadowing, 0.0, 0.0, None, (L.ROUGH_DIFFUSE,)), {
        "Lambert": L.LobeFit((), lambert, shadowing, 0.0, 0.0),
        "other Blender's": L.LobeFit((1.0,), w, other, 0.0, 0.0, None, (L.ROUGH_DIFFUSE,)),
    }


def render_errors(bpy, material, exr_path, case="stretched"):
    """Per-pixel relative RMSE of the render against the three references. ``case``:
    "stretched" (the stretched lobe above), "in the plane" (the same lobe stretched in the plane
    of incidence: aspect 1/3, against it stretched across and round), "kinds" (``_kinds_case``: Beckmann and Fresnel
    lobes), "velvet" (``_velvet_case``) or "rough" (``_rough_case``), the model's error under "model"."""
    from addon.blender.preview import render_still
    from addon.blender.preview import scene as sc
    from addon.core.material import lobes as L
    from addon.core.preview import bake_sphere, relative_rmse, sphere_layout
    from addon.tools.bench_artist import lobes_bake_brdf
    from addon.tools.bench_preview import _environment, _read_exr

    n = L.N_VIEWS
    w = np.zeros((2, n, 3))
    w[1] = 1.0
    q = np.full((1, n), ASPECT)
    q[0, 0] = 1.0  # round at normal view, as every fit
    shadowing = L.shadowing_for(bpy.app.version)
    across = L.LobeFit((ROUGHNESS,), w, shadowing, 0.0, 0.0, q)
    in_plane = L.LobeFit((ROUGHNESS,), w, shadowing, 0.0, 0.0, 1.0 / q)
    round_ = L.LobeFit((ROUGHNESS,), w, shadowing, 0.0, 0.0)
    fit, others = across, {"in the plane": in_plane, "round": round_}
    if case == "in the plane":  # the same lobe stretched in the plane (aspect 1/3), as broad edits need
        fit, others = in_plane, {"across": across, "round": round_}
    if case == "kinds":
        fit, others = _kinds_case(L, shadowing)
    if case == "velvet":
        fit, others = _velvet_case(L, shadowing)
    if case == "rough":
        fit, others = _rough_case(L, shadowing)

    env, env_path = _environment(bpy)
    layout = sphere_layout(SIZE, SIZE, 1)
    mask = layout.interior_mask()
    refs = {}
    for name, f in (("model", fit), *others.items()):
        rgb, cov = bake_sphere(lobes_bake_brdf(f), env, layout.diameter, SAMPLES, 3)
        refs[name] = layout.compose([np.dstack([rgb * cov[..., None], cov])])
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    sc.configure_render(scene, layout, "baked", samples=SAMPLES)
    scene.cycles.max_bounces = scene.cycles.diffuse_bounces = scene.cycles.glossy_bounces = 1
    sc.ensure_camera(scene, layout)
    sc.ensure_world(scene, env_path, path="osl")
    (obj,) = sc.ensure_spheres(scene, layout)
    mat = bpy.data.materials.new("stretched")
    material.apply_lobes(mat, fit)
    group = mat.node_tree.nodes["BRDF Moments edit"]
    kinds = [nd.bl_idname for nd in group.node_tree.nodes]
    if case in ("stretched", "in the plane") and "ShaderNodeNewGeometry" not in kinds:
        raise AssertionError(f"not a stretched lobes group: {group.label}")
    if case == "kinds" and (kinds.count("ShaderNodeBsdfPrincipled") != 1 or "ShaderNodeBsdfDiffuse" in kinds):
        raise AssertionError(f"not one Principled and no Diffuse: {kinds}")
    velvet_node = "ShaderNodeBsdfSheen" if bpy.app.version >= (4, 0, 0) else "ShaderNodeBsdfVelvet"
    if case == "velvet" and kinds.count(velvet_node) != 1:
        raise AssertionError(f"not one {velvet_node}: {kinds}")
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    render_still(scene, exr_path, quiet=True)
    img = _read_exr(bpy, exr_path)
    return {k: relative_rmse(img, v, mask) for k, v in refs.items()}
