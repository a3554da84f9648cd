"""BRDF Moments: a Blender extension (4.2+) that also loads as a legacy add-on (3.4-4.1).

This is the extension's entry point and the one place that gathers its parts: the operators
(``operators/``, one per file) and the glue they stand on (``addon.blender``: state, panels,
handlers, registered by ``addon.blender.registration``). Imports go one way, down: entry point,
operators, glue, engine (``addon.core``, which never imports bpy); tests/test_layout.py checks it.
"""

bl_info = {
    "name": "BRDF Moments",
    "author": "BRDF Moments developers",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Material > BRDF Moments",
    "description": "Moment profiles and moment-based editing of measured (MERL) BRDFs",
    "category": "Material",
}


def operator_classes():
    """The extension's operator classes, in the order they are registered. (Not named
    ``operators``: importing the subpackage sets that attribute of this package.)"""
    from .operators import (
        analyse,
        apply_edit,
        build_preview,
        clear_set,
        export,
        load_merl,
        load_set,
        node_bound,
        reset_sliders,
        restore_material,
        show_image,
    )

    return (
        load_merl.BRDFMOMENTS_OT_load_merl,
        analyse.BRDFMOMENTS_OT_analyse,
        reset_sliders.BRDFMOMENTS_OT_reset_sliders,
        apply_edit.BRDFMOMENTS_OT_apply_edit,
        node_bound.BRDFMOMENTS_OT_node_bound,
        restore_material.BRDFMOMENTS_OT_restore_material,
        export.BRDFMOMENTS_OT_export,
        build_preview.BRDFMOMENTS_OT_build_preview,
        show_image.BRDFMOMENTS_OT_show_image,
        load_set.BRDFMOMENTS_OT_load_set,
        clear_set.BRDFMOMENTS_OT_clear_set,
    )


def register():
    from .addon.blender import registration

    registration.register(operator_classes())


def unregister():
    from .addon.blender import registration

    registration.unregister(operator_classes())
