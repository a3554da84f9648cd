"""The preview scene in Blender: camera, a row of spheres, the world, render settings.

Mirrors ``addon.core.preview.scene``: an orthographic camera looking along +y, unit spheres at
z = 0 placed so each covers a pixel-aligned square of ``layout.diameter`` pixels. Spheres are
seen by camera rays only (no shadows or reflections of each other): the numpy reference
renders them the same way.
"""

from __future__ import annotations

import math

import bpy
import numpy as np

from ..compat import fix_sampling_pattern, node_tree

COLLECTION = "BRDF Moments Preview"
CAMERA = "BRDFM Camera"
SPHERE_MESH = "BRDFM Sphere"
WORLD = "BRDFM World"


def ensure_collection(scene):
    coll = bpy.data.collections.get(COLLECTION)
    if coll is None:
        coll = bpy.data.collections.new(COLLECTION)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def _link(obj, coll):
    if obj.name not in coll.objects:
        coll.objects.link(obj)


def ensure_camera(scene, layout):
    coll = ensure_collection(scene)
    cam = bpy.data.objects.get(CAMERA)
    if cam is None or cam.type != "CAMERA":
        data = bpy.data.cameras.new(CAMERA)
        cam = bpy.data.objects.new(CAMERA, data)
    _link(cam, coll)
    cam.data.type = "ORTHO"
    cam.data.sensor_fit = "HORIZONTAL"
    cam.data.ortho_scale = layout.ortho_scale
    cam.data.shift_x = cam.data.shift_y = 0.0
    cam.data.clip_start, cam.data.clip_end = 0.1, 100.0
    cam.location = (0.0, -10.0, 0.0)
    cam.rotation_mode = "XYZ"
    cam.rotation_euler = (math.pi / 2, 0.0, 0.0)
    scene.camera = cam
    return cam


def sphere_mesh():
    mesh = bpy.data.meshes.get(SPHERE_MESH)
    if mesh is None:
        mesh = bpy.data.meshes.new(SPHERE_MESH)
        verts, faces = uv_sphere(128, 64)
        # Filled from numpy arrays (foreach_set copies their buffers), not bmesh's
        # create_uvsphere (0.28 s in Blender 3.4) nor from_pydata (Python lists: 0.1-0.2 s
        # under load): Build Preview's finish runs on the main thread, holding the GIL.
        lengths = np.fromiter((len(f) for f in faces), np.int32, len(faces))
        flat = np.fromiter((i for f in faces for i in f), np.int32, int(lengths.sum()))
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int32)
        mesh.vertices.add(len(verts))
        mesh.vertices.foreach_set("co", np.ascontiguousarray(verts, np.float32).ravel())
        mesh.loops.add(len(flat))
        mesh.loops.foreach_set("vertex_index", flat)
        mesh.polygons.add(len(faces))
        mesh.polygons.foreach_set("loop_start", starts)
        total = bpy.types.MeshPolygon.bl_rna.properties.get("loop_total")
        if total is not None and not total.is_readonly:  # Blender 3.x needs it; 4.x derives it
            mesh.polygons.foreach_set("loop_total", lengths)
        mesh.polygons.foreach_set("use_smooth", np.ones(len(faces), bool))
        mesh.update(calc_edges=True)
    return mesh


def uv_sphere(u_segments, v_segments):
    """Unit sphere about the z axis: vertices (N, 3) and faces (triangles at the poles, quads
    between), wound counter-clockwise seen from outside (outward normals). Fine facets keep the
    silhouette round; shading uses the exact normal anyway."""
    nu, nv = int(u_segments), int(v_segments)
    theta = np.arange(1, nv) * (math.pi / nv)  # the rings, pole to pole
    phi = np.arange(nu) * (2.0 * math.pi / nu)
    ring = np.stack(
        [
            np.sin(theta)[:, None] * np.cos(phi),
            np.sin(theta)[:, None] * np.sin(phi),
            np.repeat(np.cos(theta)[:, None], nu, axis=1),
        ],
        axis=-1,
    ).reshape(-1, 3)
    verts = np.concatenate([ring, [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]])
    top, bottom = len(ring), len(ring) + 1

    def v(i, j):
        return i * nu + j % nu

    faces = [(top, v(0, j), v(0, j + 1)) for j in range(nu)]
    faces += [(v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)) for i in range(nv - 2) for j in range(nu)]
    faces += [(bottom, v(nv - 2, j + 1), v(nv - 2, j)) for j in range(nu)]
    return verts, faces


def sphere_name(k):
    return f"BRDFM Sphere {k}"


def ensure_spheres(scene, layout):
    """Objects for spheres 0..count-1 at their layout positions; extra old ones are removed."""
    coll = ensure_collection(scene)
    mesh = sphere_mesh()
    objs = []
    for k in range(layout.count):
        obj = bpy.data.objects.get(sphere_name(k))
        if obj is None or obj.type != "MESH":
            obj = bpy.data.objects.new(sphere_name(k), mesh)
        _link(obj, coll)
        obj.location = (layout.centre_x(k), 0.0, 0.0)
        obj.rotation_euler = (0.0, 0.0, 0.0)
        obj.scale = (1.0, 1.0, 1.0)
        obj.hide_render = False
        for ray in (
            "visible_diffuse",
            "visible_glossy",
            "visible_transmission",
            "visible_volume_scatter",
            "visible_shadow",
        ):
            if hasattr(obj, ray):
                setattr(obj, ray, False)
        objs.append(obj)
    k = layout.count
    while bpy.data.objects.get(sphere_name(k)) is not None:
        bpy.data.objects.remove(bpy.data.objects[sphere_name(k)])
        k += 1
    return objs


def assign_material(obj, mat):
    if len(obj.data.materials) == 0:
        obj.data.materials.append(None)  # one slot on the shared mesh; each object links its own
    slot = obj.material_slots[0]
    slot.link = "OBJECT"
    slot.material = mat


def ensure_world(scene, env_path, strength=1.0, path="osl"):
    """World = the equirectangular map (texels constant: 'Closest', as the engine assumes).

    Its importance map lights the OSL diffuse closure, at the map's own resolution: small
    bright lights need it (a 256-wide map left 29 % per-pixel noise on a Lambertian under the
    studio HDRI at 64 samples, the 1024-wide one 4.6 %). The baked path shows only emission,
    so its world needs no map at all."""
    world = bpy.data.worlds.get(WORLD) or bpy.data.worlds.new(WORLD)
    image = bpy.data.images.load(env_path, check_existing=True)
    if hasattr(world, "cycles"):
        if path == "osl":
            world.cycles.sampling_method = "MANUAL"
            world.cycles.sample_map_resolution = max(256, int(image.size[0]))
        else:
            world.cycles.sampling_method = "NONE"
    nt = node_tree(world)
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputWorld")
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = float(strength)
    tex = nt.nodes.new("ShaderNodeTexEnvironment")
    tex.image = image
    tex.interpolation = "Closest"
    tex.projection = "EQUIRECTANGULAR"
    nt.links.new(tex.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    scene.world = world
    return world


def configure_render(scene, layout, path, samples=16, engine="CYCLES"):
    """Render settings that make Cycles show what the engine computes: box filter one pixel
    wide (a pixel is its area average), no denoiser, no adaptive stopping, standard view."""
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = layout.width, layout.height, 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.film_transparent = True
    r.engine = engine
    if hasattr(r, "dither_intensity"):
        r.dither_intensity = 0.0
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    c = scene.cycles
    c.device = "CPU"
    c.samples = int(samples)
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.seed = 0
    fix_sampling_pattern(c)  # the same noise on every Blender version
    c.shading_system = path == "osl"
    # camera rays see the spheres; the diffuse closure needs one bounce to reach the world
    c.max_bounces = 1 if path == "osl" else 0
    c.diffuse_bounces = 1 if path == "osl" else 0
    c.glossy_bounces = c.transmission_bounces = c.volume_bounces = c.transparent_max_bounces = 0
    if hasattr(c, "use_light_tree"):
        c.use_light_tree = False  # one light (the world): a tree only costs build time
