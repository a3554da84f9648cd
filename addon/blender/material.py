"""The edited BRDF in the artist's own material (SPEC §4), without losing their node tree.

Apply puts one group node, "BRDF Moments edit", into the material and links it to the active
Material Output's Surface; the artist's nodes stay where they were, untouched. What the link
replaced is remembered on the material, so Restore puts it back and removes the group: the
tree is then exactly the original. Both are plain data edits inside undo-aware operators, so
Ctrl-Z undoes them.

The group holds one of
- lobes (GGX and Beckmann Glossy, GGX lobes times a Fresnel factor drawn by a Principled BSDF,
  a Velvet, a rough Diffuse) and a diffuse lobe whose colours follow the view angle through a small packed lookup
  image (``core.material.lobes``): plain Diffuse, Glossy, Principled, Velvet (4.x: Sheen), Mix,
  Layer Weight, Math and Image Texture nodes, so any engine and any Blender (EEVEE, Cycles on
  GPU, Debian's 3.4; EEVEE's fit holds no Velvet, which it draws as a diffuse closure, nor a
  rough Diffuse); an
  approximation whose error, and the least error any mix of Blender's closures reaches on the
  table (``core.material.node_bound``), the panel states;
- a Principled BSDF fitted to the edited table (``core.material.principled``): the same reach, farther
  from measured materials, but one node an artist can keep editing;
- the tabulated OSL shader reading the edited table (Cycles with OSL only): the material itself.
"""

from __future__ import annotations

import json

import bpy
import numpy as np

GROUP_NODE = "BRDF Moments edit"
KEY = "brdfm_original_surface"  # JSON [node name, output identifier] or [] (Surface unlinked)


def group_name(mat) -> str:
    return f"BRDF Moments: {mat.name}"


def output_node(tree):
    node = None
    if hasattr(tree, "get_output_node"):
        node = tree.get_output_node("ALL") or tree.get_output_node("CYCLES") or tree.get_output_node("EEVEE")
    if node is None:
        outs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
        node = next((n for n in outs if getattr(n, "is_active_output", False)), outs[0] if outs else None)
    return node


def _new_group(name):
    group = bpy.data.node_groups.new(name, "ShaderNodeTree")
    if hasattr(group, "interface"):  # Blender 4.0 and later
        group.interface.new_socket("BSDF", in_out="OUTPUT", socket_type="NodeSocketShader")
    else:  # 3.x
        group.outputs.new("NodeSocketShader", "BSDF")
    return group


def _set_input(node, names, value):
    for name in names:
        sock = node.inputs.get(name)
        if sock is not None:
            sock.default_value = value
            return True
    return False


def fill_principled(group, fit):
    """The group's content: one Principled BSDF with the fitted inputs (3.x and 4.x names)."""
    group.nodes.clear()
    out = group.nodes.new("NodeGroupOutput")
    out.location = (300, 0)
    bsdf = group.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.name = bsdf.label = "Principled (fitted to the edited table)"
    if hasattr(bsdf, "distribution"):
        bsdf.distribution = "GGX"  # the fit's single-scattering GGX
    _set_input(bsdf, ("Base Color",), (*fit.base_color, 1.0))
    _set_input(bsdf, ("Metallic",), fit.metallic)
    _set_input(bsdf, ("Roughness",), fit.roughness)
    if bsdf.inputs.get("Specular IOR Level") is not None:  # 4.x: F0 from the IOR, level 0.5 = as is
        _set_input(bsdf, ("Specular IOR Level",), 0.5)
        _set_input(bsdf, ("IOR",), fit.ior)
    else:  # 3.x: Specular 0.5 = F0 0.04
        _set_input(bsdf, ("Specular",), min(fit.specular_3x, 1.0))
    _only_the_base_layer(bsdf)
    group.links.new(bsdf.outputs[0], out.inputs[0])
    return bsdf


def _glossy_node(group, anisotropic=False, distribution="GGX"):
    # Blender 4.0 merged Glossy into the anisotropic node's idname; 3.x has both (and there the
    # anisotropic one starts at anisotropy 0.5): Glossy itself, unless the lobe is stretched
    kind = "ShaderNodeBsdfAnisotropic" if anisotropic or bpy.app.version >= (4, 0, 0) else "ShaderNodeBsdfGlossy"
    node = group.nodes.new(kind)
    node.distribution = distribution  # GGX or BECKMANN, single scattering: the model core.material.lobes fits
    _set_input(node, ("Anisotropy",), 0.0)  # isotropic unless the lookup drives it
    return node


def _only_the_base_layer(node, *more):
    """A Principled BSDF with no coat, sheen, transmission or subsurface and an untinted
    specular, whichever of those inputs this Blender has (4.x's names or 3.x's); ``more``:
    further (input, value) pairs."""
    for name, value in (
        ("Coat Weight", 0.0),
        ("Clearcoat", 0.0),
        ("Sheen Weight", 0.0),
        ("Sheen", 0.0),
        ("Transmission Weight", 0.0),
        ("Transmission", 0.0),
        ("Subsurface Weight", 0.0),
        ("Subsurface", 0.0),
        ("Specular Tint", (1.0, 1.0, 1.0, 1.0)),
        *more,
    ):
        sock = node.inputs.get(name)
        if sock is None:
            continue
        if isinstance(value, tuple) and not hasattr(sock.default_value, "__len__"):
            value = 0.0  # 3.x's Specular Tint is a float: 0 is untinted
        sock.default_value = value


def _fresnel_node(group, roughness):
    """A Principled BSDF drawing a round GGX lobe times its metal's Fresnel factor of theta_d
    (``core.material.lobes.fresnel_factor``): metallic 1, base colour black, single-scattering GGX; in 3.x
    its "Specular" (which sets that factor's IOR) at ``lobes.PRINCIPLED_3X_SPECULAR``; no coat,
    sheen, transmission, subsurface or emission; a white specular tint (4.x: the F82 tint that
    leaves Schlick's factor as it is)."""
    from ..core.material.lobes import PRINCIPLED_3X_SPECULAR

    node = group.nodes.new("ShaderNodeBsdfPrincipled")
    if hasattr(node, "distribution"):
        node.distribution = "GGX"
    _set_input(node, ("Base Color",), (0.0, 0.0, 0.0, 1.0))
    _set_input(node, ("Metallic",), 1.0)
    _set_input(node, ("Roughness",), roughness)
    _set_input(node, ("Specular",), PRINCIPLED_3X_SPECULAR)  # 3.x only
    _only_the_base_layer(node, ("Anisotropic", 0.0), ("Emission Strength", 0.0), ("Thin Film Thickness", 0.0))
    if "Emission" in node.inputs:  # 3.x: the emission colour (black: none)
        node.inputs["Emission"].default_value = (0.0, 0.0, 0.0, 1.0)
    return node


def _math(group, op, location, a, b=None, parent=None):
    """A Math node ``op`` on ``a`` and ``b`` (each a socket to link or a number)."""
    m = group.nodes.new("ShaderNodeMath")
    m.operation = op
    m.location = location
    if parent is not None:
        m.parent = parent
    for sock, v in zip(m.inputs, (a, b)):
        if v is None:
            continue
        if isinstance(v, (int, float)):
            sock.default_value = float(v)
        else:
            group.links.new(v, sock)
    return m


def _frame(group, label, location):
    frame = group.nodes.new("NodeFrame")
    frame.name = frame.label = label
    frame.location = location
    frame.label_size = 14
    return frame


def _node(group, idname, location, parent=None, label=None):
    node = group.nodes.new(idname)
    node.location = location
    if parent is not None:
        node.parent = parent
    if label is not None:
        node.name = node.label = label
    return node


def _across_plane_of_incidence(group, parent=None):
    """N x I, normalised: the tangent across the plane of incidence. Zero at normal
    view, where the fit keeps every lobe round (anisotropy 0 makes Cycles ignore the tangent)."""
    geo = _node(group, "ShaderNodeNewGeometry", (-900, 500), parent)
    cross = _node(group, "ShaderNodeVectorMath", (-700, 500), parent, "N × I")
    cross.operation = "CROSS_PRODUCT"
    group.links.new(geo.outputs["Normal"], cross.inputs[0])
    group.links.new(geo.outputs["Incoming"], cross.inputs[1])
    # a unit tangent (Cycles' own orthonormalisation renders the same without it; one node buys
    # independence from that)
    unit = _node(group, "ShaderNodeVectorMath", (-520, 500), parent, "tangent across the plane of incidence")
    unit.operation = "NORMALIZE"
    group.links.new(cross.outputs["Vector"], unit.inputs[0])
    return unit.outputs["Vector"]


def _velvet_node(group, sigma):
    """Ashikhmin's velvet (``core.material.lobes.velvet``): 3.x's Velvet BSDF (its Sigma), 4.x's
    Sheen BSDF with the Ashikhmin distribution (its Roughness is that sigma)."""
    if bpy.app.version >= (4, 0, 0):
        node = group.nodes.new("ShaderNodeBsdfSheen")
        node.distribution = "ASHIKHMIN"
        node.inputs["Roughness"].default_value = sigma
    else:
        node = group.nodes.new("ShaderNodeBsdfVelvet")
        node.inputs["Sigma"].default_value = sigma
    return node


def lobe_title(kind, roughness):
    """How a lobe's frame names it."""
    from ..core.material.lobes import BECKMANN, FRESNEL, ROUGH_DIFFUSE, VELVET

    if kind == FRESNEL:
        return f"GGX lobe × Fresnel (roughness {roughness:.3f})"
    if kind == VELVET:
        return f"Velvet (sigma {roughness:.2f})"
    if kind == ROUGH_DIFFUSE:
        return f"rough Diffuse (roughness {roughness:.2f})"
    return f"{'Beckmann' if kind == BECKMANN else 'GGX'} lobe (roughness {roughness:.3f})"


def fill_lobes(group, fit, image):
    """The group's content for a ``core.material.lobes`` fit: the view angle u = theta_o / 90° from the
    Layer Weight's facing ratio (1 - |N.I|), one Image Texture per row of the lookup ``image``
    (row r read at v = (r + 1/2) / rows: texel centres, so linear filtering never mixes rows),
    its colour driving a Diffuse BSDF (row 0), a Glossy BSDF (row k: GGX or Beckmann), a Velvet
    (``_velvet_node``) or, for a Fresnel lobe or a rough diffuse, the factor of a Mix Shader that
    mixes in a Principled BSDF (``_fresnel_node``) or a white Diffuse BSDF at the lobe's
    roughness (the row is grey, its red channel read), all added. Each closure sits in a labelled frame with
    the nodes that drive it; a diffuse colour that is black at every view draws no Diffuse BSDF.
    A stretched lobe reads its aspect q from row K + k; with the tangent across the plane of
    incidence, Cycles' anisotropy 1 / sqrt(q) - 1 (q > 1) or 1 - sqrt(q) (q < 1) gives alpha
    sqrt(q) across it and alpha / sqrt(q) in it (Cycles' mapping, the same in 3.x and 4.x)."""
    from ..core.material.lobes import BECKMANN, FRESNEL, GREY_KINDS, VELVET

    group.nodes.clear()
    out = group.nodes.new("NodeGroupOutput")
    out.location = (1300, 0)
    view = _frame(group, "view angle u = θo / 90° (the lookup's column)", (0, 0))
    facing = _node(group, "ShaderNodeLayerWeight", (-1100, 0), view, "facing 1 - |N·I|")
    facing.inputs["Blend"].default_value = 0.5  # facing = 1 - |N.I| exactly
    # u = theta_o / 90° = arccos(1 - facing) * 2 / pi, clamped to [0, 1]
    cos_o = _math(group, "SUBTRACT", (-900, 0), 1.0, facing.outputs["Facing"], view)
    theta_o = _math(group, "ARCCOSINE", (-750, 0), cos_o.outputs[0], parent=view)
    u_node = _math(group, "MULTIPLY", (-600, 0), theta_o.outputs[0], 2.0 / 3.141592653589793, view)
    u_node.use_clamp = True
    u = u_node.outputs[0]
    rows = fit.lookup_pixels().shape[0]
    tangent = None
    if fit.anisotropic:
        tangent = _across_plane_of_incidence(group, _frame(group, "tangent for the stretched lobes", (0, 0)))

    def read_row(r, y, parent, what):
        xyz = _node(group, "ShaderNodeCombineXYZ", (-350, y), parent, f"lookup row {r}")
        group.links.new(u, xyz.inputs["X"])
        xyz.inputs["Y"].default_value = (r + 0.5) / rows
        tex = _node(group, "ShaderNodeTexImage", (-180, y), parent, what)
        tex.image = image
        tex.interpolation = "Linear"
        tex.extension = "EXTEND"
        group.links.new(xyz.outputs[0], tex.inputs["Vector"])
        return tex.outputs["Color"]

    total = None
    y = -300
    for r in range(fit.weights.shape[0]):
        if r == 0 and not fit.has_diffuse:
            continue  # no diffuse part at any view
        y -= 380
        kind = fit.kinds[r - 1] if r else None
        title = "diffuse" if r == 0 else f"lobe {r}: {lobe_title(kind, fit.roughness[r - 1])}"
        frame = _frame(group, title, (0, 0))
        if r == 0:
            colour = read_row(r, y, frame, "diffuse colour per view")
            bsdf = _node(group, "ShaderNodeBsdfDiffuse", (300, y), frame, "diffuse")
            bsdf.inputs["Roughness"].default_value = 0.0
            group.links.new(colour, bsdf.inputs["Color"])
        elif kind in GREY_KINDS:
            colour = read_row(r, y, frame, "mixed-in lobe's weight per view (grey)")
            weight = _node(group, "ShaderNodeSeparateXYZ", (100, y), frame, "weight")
            group.links.new(colour, weight.inputs[0])
            if kind == FRESNEL:
                lobe = _fresnel_node(group, fit.roughness[r - 1])
            else:  # white, so that 4.x's multiple scattering is the one shape the fit models
                lobe = group.nodes.new("ShaderNodeBsdfDiffuse")
                lobe.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
                lobe.inputs["Roughness"].default_value = fit.roughness[r - 1]
            lobe.location, lobe.parent = (300, y - 60), frame
            lobe.name = lobe.label = lobe_title(kind, fit.roughness[r - 1])
            bsdf = _node(group, "ShaderNodeMixShader", (600, y), frame, "× weight")
            group.links.new(weight.outputs["X"], bsdf.inputs["Fac"])
            group.links.new(lobe.outputs[0], bsdf.inputs[2])  # the first shader input left empty: none
        elif kind == VELVET:
            colour = read_row(r, y, frame, "velvet colour per view")
            bsdf = _velvet_node(group, fit.roughness[r - 1])
            bsdf.location, bsdf.parent = (300, y), frame
            bsdf.name = bsdf.label = lobe_title(kind, fit.roughness[r - 1])
            group.links.new(colour, bsdf.inputs["Color"])
        else:
            colour = read_row(r, y, frame, "lobe colour per view")
            bsdf = _glossy_node(group, fit.anisotropic, "BECKMANN" if kind == BECKMANN else "GGX")
            bsdf.location, bsdf.parent = (300, y), frame
            bsdf.inputs["Roughness"].default_value = fit.roughness[r - 1]
            bsdf.name = bsdf.label = lobe_title(kind, fit.roughness[r - 1])
            group.links.new(colour, bsdf.inputs["Color"])
            if tangent is not None:
                q = _node(group, "ShaderNodeSeparateXYZ", (-10, y - 200), frame, "aspect q")
                group.links.new(read_row(fit.n_lobes + r, y - 200, frame, "aspect per view (grey)"), q.inputs[0])
                # anisotropy (1 - sqrt q) / max(sqrt q, 1): 1 / sqrt(q) - 1 when stretched across
                # (q > 1), 1 - sqrt(q) when stretched in the plane (q < 1)
                root = _math(group, "SQRT", (120, y - 220), q.outputs["X"], parent=frame)
                less = _math(group, "SUBTRACT", (120, y - 300), 1.0, root.outputs[0], frame)
                most = _math(group, "MAXIMUM", (120, y - 380), root.outputs[0], 1.0, frame)
                aniso = _math(group, "DIVIDE", (120, y - 460), less.outputs[0], most.outputs[0], frame)
                aniso.label = "anisotropy"
                group.links.new(aniso.outputs[0], bsdf.inputs["Anisotropy"])
                group.links.new(tangent, bsdf.inputs["Tangent"])
        if total is None:
            total = bsdf.outputs[0]
        else:
            add = _node(group, "ShaderNodeAddShader", (1000, y), None, "add")
            group.links.new(total, add.inputs[0])
            group.links.new(bsdf.outputs[0], add.inputs[1])
            total = add.outputs[0]
    if total is not None:
        group.links.new(total, out.inputs[0])
    return group


def fill_osl(group, texture_path, fit_mu, fit_sigma2, kd, samples=16):
    """The group's content: the tabulated OSL shader (Cycles with OSL)."""
    from .preview import osl as osl_path

    group.nodes.clear()
    out = group.nodes.new("NodeGroupOutput")
    out.location = (300, 0)
    node = osl_path.script_node(group, "tabulated")
    osl_path.set_table_inputs(node, texture_path, fit_mu, fit_sigma2, kd, samples=samples)
    group.links.new(node.outputs["BSDF"], out.inputs[0])
    return node


def is_applied(mat) -> bool:
    return bool(mat.node_tree is not None and mat.node_tree.nodes.get(GROUP_NODE) is not None and KEY in mat)


def apply_group(mat, label):
    """The edit's group node in ``mat``, linked to its output (the original link remembered once)."""
    if getattr(mat, "node_tree", None) is None:
        mat.use_nodes = True
    tree = mat.node_tree
    out = output_node(tree)
    if out is None:
        out = tree.nodes.new("ShaderNodeOutputMaterial")
        out.location = (300, 300)
    surface = out.inputs["Surface"]
    node = tree.nodes.get(GROUP_NODE)
    if node is None or KEY not in mat:
        if surface.is_linked:
            link = surface.links[0]
            mat[KEY] = json.dumps([link.from_node.name, link.from_socket.identifier])
        else:
            mat[KEY] = json.dumps([])
        if node is None:
            node = tree.nodes.new("ShaderNodeGroup")
            node.name = GROUP_NODE
            node.location = (out.location.x - 220, out.location.y - 220)
    group = node.node_tree or bpy.data.node_groups.get(group_name(mat)) or _new_group(group_name(mat))
    node.node_tree = group
    node.label = label
    tree.links.new(node.outputs[0], surface)
    return group


def restore(mat) -> bool:
    """Put the artist's Surface link back and remove the edit's node; False if nothing to undo."""
    tree = mat.node_tree
    if tree is None or KEY not in mat:
        return False
    saved = json.loads(mat[KEY])
    node = tree.nodes.get(GROUP_NODE)
    group = node.node_tree if node is not None else None
    out = output_node(tree)
    if node is not None:
        tree.nodes.remove(node)
    if out is not None and saved:
        src = tree.nodes.get(saved[0])
        sock = next((s for s in src.outputs if s.identifier == saved[1]), None) if src is not None else None
        if sock is not None:
            tree.links.new(sock, out.inputs["Surface"])
    del mat[KEY]
    if group is not None and group.users == 0:
        bpy.data.node_groups.remove(group)
    return True


# --- what Apply writes ---------------------------------------------------------------------------


def principled_label(fit, bound=None):
    # Blender keeps 63 bytes of a label: the error, then the bound when it is known
    said = f", bound {100 * bound:.1f} %" if bound is not None else ""
    return f"BRDF Moments edit: Principled (error {100 * fit.error:.1f} %{said})"


def lobes_label(fit):
    after = f"bound {100 * fit.bound:.1f} %" if fit.bound is not None else f"albedo {100 * fit.albedo_error:.1f} %"
    return f"BRDF Moments edit: {fit.n_lobes} lobes (error {100 * fit.error:.1f} %, {after})"


def apply_principled(mat, fit, bound=None):
    label = principled_label(fit, bound)
    group = apply_group(mat, label)
    fill_principled(group, fit)
    return group


def lookup_pixels(fit):
    """The lobes' lookup image top row first, as image files are written."""
    return np.ascontiguousarray(fit.lookup_pixels()[::-1])


def apply_lobes(mat, fit, storage="PACK", path=None, place=None):
    """The lobe mixture in ``mat``: its lookup image packed into the .blend (or next to it).
    ``path``: the lookup's file, written already by Apply's work at ``place``."""
    place = place or texture_place(storage)
    path = path or write_texture(place, "brdfm-lookup", lookup_pixels(fit))
    image = texture_image(mat, path, LOOKUP_IMAGE, place[1])
    label = lobes_label(fit)
    group = apply_group(mat, label)
    fill_lobes(group, fit, image)
    return group


def set_bound(mat, bound):
    """Keep ``node_bound`` of the applied edit with its fit (the panel states it) and in the
    group node's label."""
    state = mat.brdf_moments
    node = mat.node_tree.nodes.get(GROUP_NODE) if mat.node_tree is not None else None
    if state.artist_shader_used == "lobes":
        fit = state.lobes_fit()
        if fit is None:
            return
        fit = fit.with_bound(bound)
        state.lobes_data = json.dumps(fit.as_dict())
        if node is not None:
            node.label = lobes_label(fit)
    elif state.artist_shader_used == "principled" and state.principled_data:
        d = json.loads(state.principled_data)
        d["bound"] = float(bound)
        state.principled_data = json.dumps(d)
        if node is not None:
            node.label = principled_label(state.principled_fit(), bound)


TEXTURE_IMAGE = "BRDFM table: {}"
LOOKUP_IMAGE = "BRDFM lookup: {}"
TEXTURE_FOLDER = "brdf_moments"  # next to the .blend, when the artist chooses that


def _texture_cache():
    import os

    from .preview.osl import cache_dir

    return os.path.join(cache_dir(), "artist")


def texture_place(storage="PACK"):
    """Main thread: where Apply writes a material's texture, read from the panel and the .blend
    before its work starts: (folder, beside, the cache's files still in use). Next to a saved
    .blend when the artist chose that (their folder: written once, never pruned); else the
    bounded cache, which keeps every file an OSL edit of this .blend still reads."""
    import os

    if storage == "BESIDE" and bpy.data.filepath:
        return os.path.join(os.path.dirname(bpy.path.abspath(bpy.data.filepath)), TEXTURE_FOLDER), True, ()
    in_use = tuple(bpy.path.abspath(script.inputs["Table"].default_value) for _, script in _osl_scripts())
    return _texture_cache(), False, in_use


def _osl_scripts():
    """(material, script node) of every OSL edit in the .blend: the Script node, with its
    Table input, inside the material's edit group."""
    for mat in bpy.data.materials:
        node = mat.node_tree.nodes.get(GROUP_NODE) if mat.node_tree is not None else None
        group = node.node_tree if node is not None else None
        script = next((n for n in group.nodes if n.bl_idname == "ShaderNodeScript"), None) if group else None
        if script is not None and "Table" in script.inputs:
            yield mat, script


def write_texture(place, prefix, pixels) -> str:
    """The texture file of ``pixels`` (top row first) at ``place`` (``texture_place``). No bpy:
    Apply's work calls it, so Blender's main thread never waits on a file write. Named by its
    content; in the cache sealed, verified when found, and bounded (``limits``)."""
    import hashlib
    import os

    from ..core.file import cachefs
    from ..core.file.exr import write_exr
    from ..core.limits import ARTIST_TEXTURE_MAX_BYTES, ARTIST_TEXTURE_MAX_ENTRIES

    folder, beside, in_use = place
    stem = f"{prefix}-{hashlib.sha256(np.ascontiguousarray(pixels).tobytes()).hexdigest()[:16]}"
    if not beside:
        bounds = (ARTIST_TEXTURE_MAX_ENTRIES, ARTIST_TEXTURE_MAX_BYTES)
        return cachefs.sealed_file(folder, stem, ".exr", lambda p: write_exr(pixels, p), bounds, in_use, "brdfm-")
    path = os.path.join(folder, stem + ".exr")
    if not os.path.isfile(path):
        write_exr(pixels, path)
    return path


def texture_image(mat, path, image_name, beside):
    """Main thread: the image datablock that keeps ``mat``'s texture file with the .blend:
    packed into it, or (``beside``) the file next to it by a relative path."""
    import os

    img_name = image_name.format(mat.name)
    old = bpy.data.images.get(img_name)
    if old is not None:
        bpy.data.images.remove(old)
    img = bpy.data.images.load(path)
    img.name = img_name
    img.colorspace_settings.name = "Non-Color"
    img.use_fake_user = True
    name = os.path.basename(path)
    if beside:
        img.filepath = f"//{TEXTURE_FOLDER}/{name}"
    else:
        img.pack()
    img["brdfm_texture"] = name
    return img


def table_texture_file(mat, pixels, storage="PACK", path=None, place=None):
    """The OSL table texture of ``mat`` as a file (OSL reads files only), and an image datablock
    that keeps it with the .blend (``texture_image``). ``path``: written already by Apply's
    work, at ``place`` (``texture_place`` when its work started)."""
    place = place or texture_place(storage)
    path = path or write_texture(place, "brdfm-table", pixels)
    texture_image(mat, path, TEXTURE_IMAGE, place[1])
    return path


def apply_osl(mat, pixels, res, scene=None, path=None, place=None):
    state = mat.brdf_moments
    path = table_texture_file(mat, pixels, state.texture_storage, path, place)
    group = apply_group(mat, "BRDF Moments edit (OSL, the edited table)")
    prof = res.profiles
    fill_osl(
        group,
        path,
        res.achieved_mu_slope if res.achieved_mu_slope is not None else state.fit_mu_slope,
        res.achieved_sigma2 if res.achieved_sigma2 is not None else state.fit_sigma2,
        prof.kd,
    )
    return group


def relink_textures():
    """After a .blend is opened (maybe on another machine): point every OSL edit at its table
    texture, written out of the packed image into the cache (sealed, bounded) or found next
    to the .blend, when missing or damaged."""
    import os

    from ..core.file import cachefs
    from ..core.limits import ARTIST_TEXTURE_MAX_BYTES, ARTIST_TEXTURE_MAX_ENTRIES

    cache = os.path.abspath(_texture_cache())
    for mat, script in list(_osl_scripts()):
        img = bpy.data.images.get(TEXTURE_IMAGE.format(mat.name))
        if img is None:
            continue
        current = os.path.abspath(bpy.path.abspath(script.inputs["Table"].default_value))
        if os.path.isfile(current) and (os.path.dirname(current) != cache or cachefs.verified(current)):
            continue
        name = img.get("brdfm_texture") or os.path.basename(img.filepath)
        if img.packed_file is not None:
            data = img.packed_file.data

            def write(path, data=data):
                from ..core.file.atomic import atomic_path

                with atomic_path(path, ".exr") as tmp, open(tmp, "wb") as fh:
                    fh.write(data)

            bounds = (ARTIST_TEXTURE_MAX_ENTRIES, ARTIST_TEXTURE_MAX_BYTES)
            stem = os.path.splitext(name)[0]
            path = cachefs.sealed_file(cache, stem, ".exr", write, bounds, texture_place()[2], "brdfm-")
        else:
            path = bpy.path.abspath(img.filepath)
        if os.path.isfile(path):
            script.inputs["Table"].default_value = path
