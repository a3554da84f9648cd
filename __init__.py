"""BRDF Moments: a Blender extension (4.2+) that also loads as a legacy add-on (3.4-4.1).

Registration lives in ``addon.blender.registration``; the engine (``addon.core``) never imports bpy.
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


def register():
    from .addon.blender import registration

    registration.register()


def unregister():
    from .addon.blender import registration

    registration.unregister()
