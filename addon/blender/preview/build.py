"""Build and update the preview: sources, materials, the baked images, rendering."""

from __future__ import annotations

import contextlib
import json
import os
import sys
from collections import OrderedDict
from dataclasses import dataclass, field

import bpy
import numpy as np

from ...core.file.merl import MerlTable, read_merl
from ...core.preview import BakeCache, ModelBRDF, MomentParams, TableBRDF, bake_key, sphere_layout
from ..compat import node_tree
from . import osl as osl_path
from . import scene as sc
from .environment import load_environment, resolve_environment

PATHS = ("auto", "osl", "baked")
MODES = ("model", "tabulated")
SEED = 0


@dataclass
class PreviewInfo:
    path: str  # 'osl' or 'baked' (what 'auto' resolved to)
    mode: str  # OSL mode ('model' or 'tabulated'); 'tabulated' for baked
    layout: object  # core.preview.Layout
    materials: list  # material names, left to right
    environment: str  # HDRI path
    baked: list = field(default_factory=list)  # materials (re)baked by this call
    notes: list = field(default_factory=list)


# --- sources ---------------------------------------------------------------------------------

_SOURCES = {}  # material name -> MerlTable | MomentParams (live, not saved)
_BRDFS = OrderedDict()  # content id -> TableBRDF / ModelBRDF / fit params (a few recent)
CACHE = None


def bake_cache() -> BakeCache:
    global CACHE
    if CACHE is None:
        CACHE = BakeCache(osl_path.cache_dir())
    return CACHE


def as_source(obj):
    """A MERL path, a MerlTable, a TableBRDF (a table with its own kd split) or MomentParams."""
    if isinstance(obj, (MerlTable, MomentParams, TableBRDF)):
        return obj
    if isinstance(obj, (str, os.PathLike)):
        return read_merl(obj)
    raise TypeError(f"cannot preview a {type(obj).__name__}: give a MERL path, a MerlTable or MomentParams")


def _memo(key, make):
    if key in _BRDFS:
        _BRDFS.move_to_end(key)
        return _BRDFS[key]
    value = make()
    _BRDFS[key] = value
    while len(_BRDFS) > 6:
        _BRDFS.popitem(last=False)
    return value


def brdf_of(source, profiles=None):
    """The engine BRDF of a source (tables keep their profiles: memoized by content)."""
    if isinstance(source, MomentParams):
        return ModelBRDF(source)
    if isinstance(source, TableBRDF):
        return source
    key = ("table", id(source), source.rho.shape)
    # keyed by identity: the memoized TableBRDF holds the table, so the id stays its own
    return _memo(key, lambda: TableBRDF(source, profiles))


def model_params(source, profiles=None) -> MomentParams:
    """The moment model of a source: as given, or fitted to a table (Sec. 3.4 fits)."""
    if isinstance(source, MomentParams):
        return source
    from ...core.fits.curves import fit_material

    brdf = brdf_of(source, profiles)
    return _memo(("fit", brdf.content_key()), lambda: MomentParams.from_fit(fit_material(brdf.profiles), brdf.kd))


def set_source(material, source):
    """Point a preview material at a new source (a slider moved): the baked path re-bakes it on
    the next ``refresh_baked``; the OSL model path only needs ``update_model``."""
    src = as_source(source)
    _SOURCES[material.name] = src
    material["brdfm_kind"] = "model" if isinstance(src, MomentParams) else "table"
    if isinstance(src, MomentParams):
        material["brdfm_params"] = json.dumps(src.__dict__)
    table = src.table if isinstance(src, TableBRDF) else src
    if isinstance(table, MerlTable) and table.path:
        material["brdfm_table_path"] = os.path.abspath(table.path)
    return src


def source_of(material):
    """The live source of a preview material (reloaded from its file or parameters if needed)."""
    if material.name in _SOURCES:
        return _SOURCES[material.name]
    kind = material.get("brdfm_kind")
    if kind == "model" and material.get("brdfm_params"):
        return set_source(material, MomentParams(**json.loads(material["brdfm_params"])))
    if kind == "table" and material.get("brdfm_table_path"):
        return set_source(material, read_merl(material["brdfm_table_path"]))
    return None


# --- materials --------------------------------------------------------------------------------


def _fresh_tree(mat):
    nt = node_tree(mat)
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    return nt, out


def baked_material(mat, image):
    """Emission of the baked image, looked up at the sphere's object-space (x, z): texel = pixel."""
    nt, out = _fresh_tree(mat)
    coord = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    comb = nt.nodes.new("ShaderNodeCombineXYZ")
    nt.links.new(coord.outputs["Object"], sep.inputs[0])
    for axis, target in (("X", 0), ("Z", 1)):
        m = nt.nodes.new("ShaderNodeMath")
        m.operation = "MULTIPLY_ADD"
        m.inputs[1].default_value = 0.5
        m.inputs[2].default_value = 0.5
        nt.links.new(sep.outputs[axis], m.inputs[0])
        nt.links.new(m.outputs[0], comb.inputs[target])
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.name = "BRDFM Bake"
    tex.image = image
    tex.interpolation = "Closest"
    tex.extension = "EXTEND"
    nt.links.new(comb.outputs[0], tex.inputs["Vector"])
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = 1.0
    nt.links.new(tex.outputs["Color"], em.inputs["Color"])
    nt.links.new(em.outputs[0], out.inputs["Surface"])
    mat["brdfm_path"] = "baked"


def osl_material(mat, mode):
    nt, out = _fresh_tree(mat)
    node = osl_path.script_node(nt, mode)
    node.name = "BRDFM OSL"
    nt.links.new(node.outputs["BSDF"], out.inputs["Surface"])
    mat["brdfm_path"] = "osl"
    mat["brdfm_mode"] = mode
    return node


def update_model(material, params, samples=None):
    """Slider update in OSL model mode: node inputs only, no re-synthesis, no bake."""
    node = material.node_tree.nodes.get("BRDFM OSL") if material.node_tree else None
    if node is None or material.get("brdfm_mode") != "model":
        raise ValueError(f"{material.name}: not an OSL moment-model preview material")
    set_source(material, params)
    ins = node.inputs
    osl_path.set_model_inputs(
        node,
        params,
        samples if samples is not None else ins["Samples"].default_value,
        ins["Environment"].default_value,
        ins["Strength"].default_value,
    )


# --- the baked path ----------------------------------------------------------------------------


def _visible(obj):
    return not obj.hide_render and all(not c.hide_render for c in obj.users_collection)


def preview_spheres(scene):
    out = []
    k = 0
    while (obj := bpy.data.objects.get(sc.sphere_name(k))) is not None:
        if obj.name in scene.objects:
            out.append(obj)
        k += 1
    return out


def scene_layout(scene):
    r = scene.render
    w = max(1, int(r.resolution_x * r.resolution_percentage / 100))
    h = max(1, int(r.resolution_y * r.resolution_percentage / 100))
    return sphere_layout(w, h, max(1, len(preview_spheres(scene))))


def refresh_baked(scene, lobe_samples=None, cache=None):
    """Bake what the scene shows and nothing else: materials on visible preview spheres, at
    the render's resolution, whose content (material, map, resolution, settings) changed since
    their image was made. Returns the names of the materials whose image was rewritten."""
    cache = cache or bake_cache()
    lobe_samples = int(lobe_samples or scene.get("brdfm_bake_samples", 64))
    env_path = scene.get("brdfm_env")
    if not env_path:
        raise ValueError("no preview environment in this scene: build the preview first")
    layout = scene_layout(scene)
    d = layout.diameter
    env = None
    done = []
    for obj in preview_spheres(scene):
        if not _visible(obj) or not obj.material_slots or obj.material_slots[0].material is None:
            continue
        mat = obj.material_slots[0].material
        if mat.get("brdfm_path") != "baked" or mat.name in done:
            continue
        source = source_of(mat)
        if source is None:
            continue
        env = env or load_environment(env_path)
        brdf = brdf_of(source)
        key = bake_key(brdf, env, d, lobe_samples, SEED)
        img = mat.node_tree.nodes["BRDFM Bake"].image if "BRDFM Bake" in mat.node_tree.nodes else None
        if img is not None and img.get("brdfm_key") == key and tuple(img.size) == (d, d) and img.has_data:
            continue
        rgb, _cov, key = cache.get(brdf, env, d, lobe_samples, SEED)
        img = _write_bake_image(mat, rgb)
        img["brdfm_key"] = key
        done.append(mat.name)
    return done


def _write_bake_image(mat, rgb):
    d = rgb.shape[0]
    name = f"BRDFM bake {mat.name}"
    img = bpy.data.images.get(name)
    if img is not None and (tuple(img.size) != (d, d) or not img.is_float):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, d, d, alpha=True, float_buffer=True)
        img.colorspace_settings.name = "Non-Color"  # before the pixels: they are linear radiance
    rgba = np.ones((d, d, 4), np.float32)
    rgba[..., :3] = rgb[::-1]  # bake rows go top-down, Blender's bottom-up
    img.pixels.foreach_set(rgba.ravel())
    img.update()
    node = mat.node_tree.nodes.get("BRDFM Bake")
    if node is not None:
        node.image = img
    return img


# --- building ---------------------------------------------------------------------------------


def resolve_path(path):
    if path not in PATHS:
        raise ValueError(f"preview path must be one of {PATHS}, got {path!r}")
    if path == "auto":
        return "osl" if osl_path.osl_available()[0] else "baked"
    if path == "osl":
        ok, why = osl_path.osl_available()
        if not ok:
            raise osl_path.OSLUnavailable(why)
    return path


def build_row(
    scene,
    sources,
    *,
    labels=None,
    path="auto",
    mode="model",
    env=None,
    size=256,
    samples=16,
    lobe_samples=16,
    bake_samples=64,
    engine="CYCLES",
    profiles=None,
    osl_filter=1.0,
) -> PreviewInfo:
    """A row of spheres, one per source (MERL path, MerlTable or MomentParams), left to right.

    ``osl_filter``: 1 looks the map up prefiltered to each OSL sample's footprint (less noise,
    a little blur of small lights); 0 reads single texels (unbiased)."""
    if mode not in MODES:
        raise ValueError(f"OSL mode must be one of {MODES}, got {mode!r}")
    srcs = [as_source(s) for s in sources]
    if not srcs:
        raise ValueError("nothing to preview")
    labels = list(labels) if labels else [f"Sphere {k}" for k in range(len(srcs))]
    path = resolve_path(path)
    env_path = resolve_environment(env)
    w, h = (size, size) if isinstance(size, int) else (int(size[0]), int(size[1]))
    layout = sphere_layout(w, h, len(srcs))
    sc.configure_render(scene, layout, path, samples, engine)
    sc.ensure_camera(scene, layout)
    sc.ensure_world(scene, env_path, path=path)
    scene["brdfm_env"] = env_path
    scene["brdfm_bake_samples"] = int(bake_samples)
    objs = sc.ensure_spheres(scene, layout)
    names, notes = [], []
    profiles = profiles or [None] * len(srcs)
    for obj, src, label, prof in zip(objs, srcs, labels, profiles):
        mat = bpy.data.materials.get(f"BRDFM {label}") or bpy.data.materials.new(f"BRDFM {label}")
        set_source(mat, src)
        if path == "osl":
            node = osl_material(mat, mode)
            if mode == "model":
                osl_path.set_model_inputs(
                    node,
                    model_params(src, prof),
                    lobe_samples,
                    env_path,
                    pixel_samples=samples,
                    filter_scale=osl_filter,
                )
            else:
                if isinstance(src, MomentParams):
                    raise ValueError(f"{label}: tabulated mode needs a MERL table, not moment parameters")
                brdf = brdf_of(src, prof)
                fit = model_params(src, prof)
                osl_path.set_table_inputs(
                    node,
                    osl_path.write_table_texture(brdf),
                    fit.mu_slope,
                    fit.sigma2,
                    brdf.kd,
                    lobe_samples,
                    env_path,
                    pixel_samples=samples,
                    filter_scale=osl_filter,
                )
        else:
            if not isinstance(src, MomentParams):
                brdf_of(src, prof)
            baked_material(mat, bpy.data.images.get(f"BRDFM bake {mat.name}"))
        sc.assign_material(obj, mat)
        names.append(mat.name)
    info = PreviewInfo(path, mode if path == "osl" else "tabulated", layout, names, env_path, notes=notes)
    if path == "baked":
        info.baked = refresh_baked(scene, bake_samples)
    return info


def build_preview(scene, original, edited=None, **options) -> PreviewInfo:
    """Original and (if given) edited side by side; see ``build_row`` for the options."""
    sources = [original] if edited is None else [original, edited]
    labels = options.pop("labels", None) or (["Original"] if edited is None else ["Original", "Edited"])
    return build_row(scene, sources, labels=labels, **options)


@contextlib.contextmanager
def quiet_stdout():
    """Blender prints render progress on the C-level stdout: send it to /dev/null."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def render_still(scene, out_path, quiet=False, labels=None):
    """Render the scene to ``out_path``: .png display-referred (Standard view, sRGB, 8-bit RGBA),
    .exr linear scene radiance (32-bit float RGBA). Written atomically. ``quiet`` keeps
    Blender's progress lines off stdout; ``labels``: one per sphere, drawn above it."""
    from ...core.file.atomic import atomic_path

    ext = os.path.splitext(os.fspath(out_path))[1].lower()
    settings = scene.render.image_settings
    if ext == ".png":
        settings.file_format, settings.color_mode, settings.color_depth = "PNG", "RGBA", "8"
    elif ext == ".exr":
        settings.file_format, settings.color_mode, settings.color_depth = "OPEN_EXR", "RGBA", "32"
        settings.exr_codec = "ZIP"
    else:
        raise ValueError(f"{out_path}: output must end in .png or .exr")
    scene.render.use_file_extension = False
    if scene.get("brdfm_env") and any(
        (
            o.material_slots
            and o.material_slots[0].material is not None
            and o.material_slots[0].material.get("brdfm_path") == "baked"
        )
        for o in preview_spheres(scene)
    ):
        refresh_baked(scene)
    with atomic_path(out_path, ext) as tmp:
        scene.render.filepath = tmp
        with quiet_stdout() if quiet else contextlib.nullcontext():
            bpy.ops.render.render(write_still=True, scene=scene.name)
        if not os.path.exists(tmp) or os.path.getsize(tmp) == 0:
            raise RuntimeError(f"{out_path}: Blender wrote no image")
        if labels:
            _label_file(tmp, labels)
    return os.path.abspath(out_path)


def _label_file(path, labels):
    """Draw the spheres' labels into the image file at ``path`` (rewritten in its own format)."""
    import numpy as np

    from ...core.preview import sphere_layout
    from ..images import label_image

    img = bpy.data.images.load(path, check_existing=False)
    try:
        w, h = img.size
        buf = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(buf)
        rgba = label_image(buf.reshape(h, w, 4)[::-1].copy(), sphere_layout(w, h, len(labels)), labels)
        img.pixels.foreach_set(np.ascontiguousarray(rgba[::-1]).ravel())
        img.filepath_raw = path
        img.save()
    finally:
        bpy.data.images.remove(img)
