"""The preview in Cycles under the bpy wheel: OSL shaders, baked images, the content cache, the CLI.

Renders are small (48-64 px, 16 samples) so the file runs in about a minute; render speed is
measured by ``python -m addon bench --only preview``, not here.
"""

import math
import os
import subprocess
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.blender  # Cycles through the bpy module

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
A, B = 1.0, 0.5  # sky L = A + B z: a Lambertian of albedo 0.8 shows 0.8 (A + 2 B n_z / 3)


@pytest.fixture(scope="module")
def bpy(tmp_path_factory):
    os.environ.setdefault("BLENDER_USER_RESOURCES", str(tmp_path_factory.mktemp("blender-user")))
    from addon.wheel import import_bpy

    return import_bpy()


@pytest.fixture
def scene(bpy):
    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context.scene


@pytest.fixture(scope="module")
def sky(bpy, tmp_path_factory):
    from addon.blender.preview import write_environment
    from addon.core.preview import Environment

    env = Environment.from_function(lambda d: np.repeat(A + B * d[:, 2:3], 3, axis=1), 256, 128)
    return write_environment(env.pixels, str(tmp_path_factory.mktemp("env") / "sky.exr"))


@pytest.fixture(scope="module")
def sun(bpy, tmp_path_factory):
    """A dim sky and a small bright sun up and to the camera's left, so a highlight shows."""
    from addon.blender.preview import write_environment
    from addon.core.preview import Environment

    s = np.array([-0.3, -0.8, 0.5]) / np.linalg.norm([-0.3, -0.8, 0.5])
    env = Environment.from_function(
        lambda d: np.repeat(0.05 + 300.0 * (d @ s > math.cos(0.04))[:, None], 3, 1), 1024, 512
    )
    return write_environment(env.pixels, str(tmp_path_factory.mktemp("env") / "sun.exr"))


def read_exr(bpy, path):
    img = bpy.data.images.load(path)
    w, h = img.size
    buf = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(buf)
    bpy.data.images.remove(img)
    return buf.reshape(h, w, 4)[::-1]  # top row first, as the engine's images


def closed_form(layout):
    from addon.core.preview.scene import texel_positions

    mask = layout.interior_mask()
    jj, ii = np.nonzero(mask)
    k = np.searchsorted(np.asarray(layout.lefts), ii, side="right") - 1
    _, z = texel_positions(layout.diameter, ii - np.asarray(layout.lefts)[k], jj - layout.top, 0.5, 0.5)
    return mask, 0.8 * (A + 2.0 * B * z / 3.0)


def lambert_as_lobe(sample_table):
    """The Lambertian with no kd split: all of it through the shaders' sampling."""
    from addon.core.preview import MomentParams, TableBRDF
    from addon.core.profiles.compute import compute_profiles

    table = sample_table("lambertian")
    a = 0.8 * math.pi  # alpha = rho pi^2 with rho = 0.8/pi: the lobe is the uniform square
    model = MomentParams((a,) * 3, (a,) * 3, (0.0,) * 3, 0.8, 1.2, 0.0, math.pi**2 / 12)
    return model, TableBRDF(table, compute_profiles(table, split=False))


def test_osl_shaders_compile_under_the_bpy_wheel(bpy, scene, tmp_path):
    from addon.blender.compat import node_tree
    from addon.blender.preview import compile_shader, osl_available
    from addon.blender.preview.osl import SHADERS, script_node

    assert osl_available() == (True, "")
    for mode, name in SHADERS.items():
        oso = compile_shader(name, folder=str(tmp_path))
        assert os.path.getsize(oso) > 0
        mat = bpy.data.materials.new(f"probe {mode}")
        node = script_node(node_tree(mat), mode)
        assert "BSDF" in node.outputs and "Environment" in node.inputs and "Samples" in node.inputs


def test_baked_lambertian_render_matches_the_closed_form(scene, sky, sample_table, tmp_path, bpy):
    """Through Cycles: bake, float image, emission, box filter. Tolerance 2e-3: the map holds
    the sky texel-constant (256 x 128), which moves the irradiance by about 1e-3."""
    from addon.blender.preview import build_preview, render_still

    info = build_preview(scene, sample_table("lambertian"), path="baked", env=sky, size=64, samples=4)
    assert info.path == "baked" and info.baked == ["BRDFM Original"]
    img = read_exr(bpy, render_still(scene, str(tmp_path / "lambert.exr")))
    mask, want = closed_form(info.layout)
    np.testing.assert_allclose(img[mask][:, 0], want, rtol=2e-3)
    assert np.all(img[mask][:, 3] == pytest.approx(1.0))
    assert np.all(img[~info.layout.interior_mask() & (img[..., 3] == 0)][:, :3] == 0)


@pytest.mark.parametrize("mode", ["model", "tabulated"])
def test_osl_lambertian_render_matches_the_closed_form(mode, scene, sky, sample_table, tmp_path, bpy):
    """OSL, with the Lambertian carried by the lobe (no kd): 16 pixel samples x 16 lobe samples.
    Unbiased, so the mean over the disk is within 1 %; the per-pixel spread is noise, bounded
    by a per-sample relative spread of 1.5 (measured 0.13 model, 0.7 tabulated)."""
    from addon.blender.preview import build_preview, render_still

    model, table = lambert_as_lobe(sample_table)
    info = build_preview(
        scene, model if mode == "model" else table, path="osl", mode=mode, env=sky, size=48, samples=16, lobe_samples=16
    )
    img = read_exr(bpy, render_still(scene, str(tmp_path / f"osl-{mode}.exr")))
    mask, want = closed_form(info.layout)
    rel = img[mask][:, 0] / want - 1
    assert abs(rel.mean()) < 0.01
    assert np.sqrt(np.mean(rel**2)) < 1.5 / math.sqrt(16 * 16)


def test_osl_diffuse_closure_carries_kd(scene, sky, sample_table, tmp_path, bpy):
    """kd split on: no specular part, so only the diffuse closure (Cycles' own path tracing).
    64 samples: mean within 1 %, per-pixel rms within 3 % (measured 1.1 %)."""
    from addon.blender.preview import build_preview, render_still

    info = build_preview(scene, sample_table("lambertian"), path="osl", mode="tabulated", env=sky, size=48, samples=64)
    img = read_exr(bpy, render_still(scene, str(tmp_path / "kd.exr")))
    mask, want = closed_form(info.layout)
    rel = img[mask][:, 0] / want - 1
    assert abs(rel.mean()) < 0.01 and np.sqrt(np.mean(rel**2)) < 0.03


@pytest.mark.parametrize("mode", ["model", "tabulated"])
def test_osl_glossy_agrees_with_the_numpy_reference(mode, scene, sample_table, tmp_path, bpy):
    """Same view, map and BRDF in two renderers: the frames, the mapping and the measure agree."""
    from addon.blender.preview import build_preview, load_environment, render_still, resolve_environment
    from addon.blender.preview.build import brdf_of, model_params
    from addon.core.preview import ModelBRDF, render_reference

    table = sample_table("ggx_glossy")
    env_path = resolve_environment("courtyard")
    info = build_preview(scene, table, path="osl", mode=mode, env=env_path, size=40, samples=32, lobe_samples=16)
    img = read_exr(bpy, render_still(scene, str(tmp_path / "glossy.exr")))
    brdf = ModelBRDF(model_params(table)) if mode == "model" else brdf_of(table)
    ref = render_reference(info.layout, [brdf], load_environment(env_path), spp=256, seed=3)
    mask = info.layout.interior_mask()
    got, want = img[mask][:, :3], ref[mask][:, :3]
    assert got.mean() == pytest.approx(want.mean(), rel=0.02)
    # pixel by pixel, within the noise of 32 x 16 samples (measured 10 %; the mean agrees to 0.5 %)
    assert np.sqrt(np.mean((got - want) ** 2)) / np.sqrt(np.mean(want**2)) < 0.15


def highlight(img, layout, k):
    """(peak, area above half the peak, mean) of sphere k's interior luminance."""
    d, left, top = layout.diameter, layout.lefts[k], layout.top
    tile = img[top : top + d, left : left + d, :3].mean(axis=2)
    inner = layout.interior_mask()[top : top + d, left : left + d]
    v = np.where(inner, tile, 0.0)
    # a 3x3 box blur first, so one noisy pixel is not "the peak"
    p = np.pad(v, 1)
    blur = sum(p[i : i + d, j : j + d] for i in range(3) for j in range(3)) / 9.0
    peak = blur[inner].max()
    return peak, int((blur[inner] > 0.5 * peak).sum()), v[inner].mean()


@pytest.mark.parametrize("path", ["osl", "baked"])
def test_larger_variance_gives_a_lower_blurrier_highlight(path, scene, sun, tmp_path, bpy):
    """The slider moved sigma2 from 0.004 to 0.016 (4x): the highlight of the sun must get
    lower and wider (its area roughly follows the variance) while the energy stays."""
    from addon.blender.preview import build_preview, render_still
    from addon.core.preview import MomentParams

    original = MomentParams((0.8,) * 3, (0.8,) * 3, (0.0,) * 3, 0.8, 1.3, -1.0, 0.004, (0.02,) * 3)
    edited = original.edited(sigma2=0.016)
    info = build_preview(
        scene,
        original,
        edited,
        path=path,
        mode="model",
        env=sun,
        size=(160, 80),
        samples=16,
        lobe_samples=32,
        bake_samples=32,
    )
    img = read_exr(bpy, render_still(scene, str(tmp_path / f"sigma-{path}.exr")))
    p0, a0, m0 = highlight(img, info.layout, 0)
    p1, a1, m1 = highlight(img, info.layout, 1)
    assert p1 < 0.6 * p0
    assert a1 > 2.0 * a0
    assert m1 == pytest.approx(m0, rel=0.15)


def test_touching_one_of_ten_materials_rebakes_one(scene, sun, bpy):
    from addon.blender.preview import build_row, refresh_baked, set_source, source_of
    from addon.core.preview import BakeCache, MomentParams

    base = MomentParams((0.5,) * 3, (0.6,) * 3, (0.2,) * 3, 0.8, 1.3, -1.0, 0.02, (0.03,) * 3)
    params = [base.edited(strength=0.5 + 0.1 * k) for k in range(10)]
    import addon.blender.preview.build as build

    build.CACHE = BakeCache()  # count bakes from zero (no disk cache)
    info = build_row(
        scene, params, labels=[f"m{k}" for k in range(10)], path="baked", env=sun, size=(200, 24), bake_samples=4
    )
    assert sorted(info.baked) == sorted(f"BRDFM m{k}" for k in range(10))
    assert len(build.CACHE.computed) == 10
    assert refresh_baked(scene) == []  # nothing changed, nothing baked
    mat = bpy.data.materials["BRDFM m3"]
    set_source(mat, source_of(mat).edited(sigma2=0.05))
    assert refresh_baked(scene) == ["BRDFM m3"]
    assert len(build.CACHE.computed) == 11
    # a hidden sphere is not baked, however its material changes; shown again, it is
    hidden = bpy.data.objects["BRDFM Sphere 6"]
    hidden.hide_render = True
    set_source(bpy.data.materials["BRDFM m6"], params[6].edited(mu_slope=-0.8))
    assert refresh_baked(scene) == []
    hidden.hide_render = False
    assert refresh_baked(scene) == ["BRDFM m6"]
    # the render's resolution is part of what is shown
    scene.render.resolution_percentage = 50
    assert len(refresh_baked(scene)) == 10
    assert len(build.CACHE.computed) == 22
    build.CACHE = None


def test_render_command(sky, tmp_path, sample_table):
    import samples

    path = samples.sample_path("lambertian")
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    out = tmp_path / "render.exr"
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "addon",
            "render",
            path,
            "--edited",
            path,
            "--path",
            "baked",
            "--env",
            sky,
            "--size",
            "48",
            "--samples",
            "4",
            "--out",
            str(out),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith(f"wrote {out}") and "baked" in res.stdout
    import OpenEXR

    pix = OpenEXR.File(str(out)).channels()["RGBA"].pixels
    assert pix.shape == (48, 48, 4) and pix.dtype == np.float32
    from addon.core.preview import sphere_layout

    mask, want = closed_form(sphere_layout(48, 48, 2))
    np.testing.assert_allclose(pix[mask][:, 0], want, rtol=2e-3)
    png = tmp_path / "render.png"
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "addon",
            "render",
            path,
            "--path",
            "baked",
            "--env",
            sky,
            "--size",
            "32",
            "--out",
            str(png),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert res.returncode == 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for bad, fault in (
        (["--out", str(tmp_path / "x.jpg")], "x.jpg: the output must end in .png"),
        (["--env", "nowhere", "--out", str(png)], "nowhere: no such bundled environment"),
    ):
        res = subprocess.run(
            [sys.executable, "-m", "addon", "render", path, *bad],
            cwd=ROOT,
            capture_output=True,
            text=True,
            env=env,
            timeout=300,
        )
        assert res.returncode == 2 and fault in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_the_preview_sphere_is_closed_round_and_faces_out(scene, bpy):
    """The sphere mesh is built from arrays (bmesh's uvsphere froze Blender 3.4 for 0.28 s):
    every vertex on the unit sphere, every edge shared by two faces, every normal outward."""
    from addon.blender.preview import scene as sc

    mesh = sc.sphere_mesh()
    n_v, n_f = len(mesh.vertices), len(mesh.polygons)
    co = np.empty(3 * n_v)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    np.testing.assert_allclose(np.linalg.norm(co, axis=1), 1.0, atol=1e-6)
    assert co[:, 2].max() == pytest.approx(1.0) and co[:, 2].min() == pytest.approx(-1.0)
    assert n_f == 128 * 64 and n_v == 128 * 63 + 2
    # Closed: Euler characteristic 2 and no edge on one face only.
    edges = {}
    for poly in mesh.polygons:
        vs = list(poly.vertices)
        for a, b in zip(vs, vs[1:] + vs[:1]):
            edges[frozenset((a, b))] = edges.get(frozenset((a, b)), 0) + 1
    assert set(edges.values()) == {2} and n_v - len(edges) + n_f == 2
    assert len(mesh.edges) == len(edges) and not mesh.validate()  # validate: True if it had to fix something
    normals, centres = np.empty(3 * n_f), np.empty(3 * n_f)
    mesh.polygons.foreach_get("normal", normals)
    mesh.polygons.foreach_get("center", centres)
    outward = np.einsum("ij,ij->i", normals.reshape(-1, 3), centres.reshape(-1, 3))
    assert outward.min() > 0.9
    assert all(p.use_smooth for p in mesh.polygons)
