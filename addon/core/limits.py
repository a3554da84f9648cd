"""Every size, count and sample bound, declared once (SPEC §7).

The command line (argparse) and the extension (operator and panel properties) both read
these, so a value refused in one is refused in the other. Each bound is well above what a
user needs and well below what would exhaust this machine (2 cores, a few GB).
"""

from __future__ import annotations

# --- analysis -------------------------------------------------------------------------------
MAX_ELEVATIONS = 360  # view elevations (0.25 deg steps); the slice operator grows ~4 MB per view
MAX_ORDER = 4  # highest moment order (the paper's)
MAX_INPUTS = 10_000  # files given to fit / analyze
MAX_JOBS = 64  # analyze worker processes

# --- preview and render ---------------------------------------------------------------------
MAX_RENDER_SIZE = 4096  # render --size, Build Preview sphere size, in pixels
MAX_SAMPLES = 4096  # Cycles samples per pixel
MAX_LOBE_SAMPLES = 1024  # OSL directions per shading point
MAX_BAKE_SAMPLES = 4096  # baked-path directions per texel

# --- input files ----------------------------------------------------------------------------
MAX_IMAGE_SIDE = 16384  # width or height of an environment map
MAX_IMAGE_PIXELS = 8192 * 4096  # 33.5 M pixels: about 540 MB as Blender's float RGBA
MAX_IMAGE_BYTES = 1 << 30  # an .exr/.hdr file on disk
MAX_PROFILES_JSON_BYTES = 64 << 20  # a profiles JSON given to fit
MAX_JSON_DEPTH = 32  # nesting of any JSON read
MAX_JSON_LIST = MAX_ELEVATIONS  # values per profile list
MAX_NBRDF_BYTES = 64 << 20  # a Neural-BRDF .npz
MAX_NBRDF_MEMBERS = 6 * 2000  # arrays in one .npz: six per network, up to 2000 networks
MAX_CACHE_ENTRY_BYTES = 1 << 30  # one cache file (the largest operator part is ~200 MB)
MAX_SET_MATERIALS = 5000  # materials of an analysed set (fits.json) shown on the region plot
MAX_SET_JSON_BYTES = 10 << 20  # that fits.json: analyze writes ~1.3 KB a material, 6.5 MB at 5000

# --- caches on disk (least recently used goes first) ------------------------------------------
OPERATOR_CACHE_MAX_ENTRIES = 8  # slice operators (~370 MB each at 90 views, 4 MB for one view)
OPERATOR_CACHE_MAX_BYTES = 3 << 30
BAKE_CACHE_MAX_ENTRIES = 256  # baked spheres (~1 MB each at 256 px)
BAKE_CACHE_MAX_BYTES = 512 << 20
TABLE_TEXTURE_MAX_ENTRIES = 16  # OSL table textures (~17 MB each)
TABLE_TEXTURE_MAX_BYTES = 400 << 20
EDITS_CACHE_MAX_ENTRIES = 16  # re-synthesized tables from Apply (35 MB each)
EDITS_CACHE_MAX_BYTES = 600 << 20


def check_int(value, name, low, high):
    """``value`` as an int in [low, high]; ValueError naming the parameter otherwise."""
    try:
        v = int(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}: not a whole number: {value!r}") from None
    if isinstance(value, float) and v != value:
        raise ValueError(f"{name}: not a whole number: {value!r}")
    if not low <= v <= high:
        raise ValueError(f"{name}: must be between {low} and {high}, got {v}")
    return v
