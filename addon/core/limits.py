"""Every size, count and sample bound, declared once (SPEC §7).

The command line (argparse) and the extension (operator and panel properties) both read
these, so a value refused in one is refused in the other. Each bound is well above what a
user needs and well below what would exhaust this machine (2 cores, a few GB).
"""

from __future__ import annotations

import numbers

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
MAX_REFERENCE_SAMPLES = 1 << 16  # the converged reference's samples per pixel (benchmarks: 16384)
MAX_SPHERES = 64  # spheres in one preview row
MAX_SEED = 2**63 - 1  # a random seed (numpy takes any non-negative integer; this bounds its key)

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
MAX_SHADER_SOURCE_BYTES = 1 << 20  # one of the add-on's OSL sources (~20 KB)
MAX_JOURNAL_ENTRY_BYTES = 1 << 16  # one record of the journal of temporaries
MAX_SET_MATERIALS = 5000  # materials of an analysed set (fits.json) shown on the region plot
MAX_SET_JSON_BYTES = 10 << 20  # that fits.json: analyze writes ~1.3 KB a material, 6.5 MB at 5000

# --- caches on disk (least recently used goes first) ------------------------------------------
OPERATOR_CACHE_MAX_ENTRIES = 8  # slice operators (~370 MB each at 90 views, 4 MB for one view)
OPERATOR_CACHE_MAX_BYTES = 3 << 30
BAKE_CACHE_MAX_ENTRIES = 256  # baked spheres (~1 MB each at 256 px)
BAKE_CACHE_MAX_BYTES = 512 << 20
TABLE_TEXTURE_MAX_ENTRIES = 16  # OSL table textures (~17 MB each)
TABLE_TEXTURE_MAX_BYTES = 400 << 20
ARTIST_TEXTURE_MAX_ENTRIES = 32  # textures of the artists' materials: OSL tables (~17 MB), lobe lookups
ARTIST_TEXTURE_MAX_BYTES = 600 << 20
EDITS_CACHE_MAX_ENTRIES = 16  # re-synthesized tables from Apply (35 MB each)
EDITS_CACHE_MAX_BYTES = 600 << 20


# --- every numeric input: a declared finite range --------------------------------------------
# One table for the command line's flags, the extension's properties and the engine's public
# functions (every size, count and slider value they take; tests/test_ranges.py finds them), so
# that a value refused in one is refused in all, with one line naming the input and its range.
# A range bounds what is accepted at all; inside it the engine may still clamp to what a
# material can reach (the edit's reachable region), with a warning.

MAX_ENERGY_SCALE = 16.0  # strength, colour, grazing boost: 16x the measured energy
MU_SLOPE_RANGE = (-2.0, 0.0)  # the panel's slider: [-1, 0] widened to hold measured slopes
SIGMA2_RANGE = (1e-8, 0.8224670334241132)  # (0, pi^2/12]: a Lambertian slice's variance
ROUGHNESS_RANGE = (0.05, 20.0)  # the roughness edit's slope-space scale (core.edit.roughness)
MAX_CORRELATION_A = 100.0  # |a| of the correlation quadratic; analysed sets give |a| < 2


class Range:
    """The accepted values of one numeric input: [low, high], whole numbers if ``integer``;
    ``flag`` is its name on the command line, used in the one-line error."""

    __slots__ = ("name", "low", "high", "integer", "flag")

    def __init__(self, name, low, high, integer=False, flag=None):
        self.name, self.low, self.high, self.integer = name, low, high, integer
        self.flag = flag or "--" + name.replace("_", "-")

    def describe(self) -> str:
        return f"between {self.low:g} and {self.high:g}" + (" (a whole number)" if self.integer else "")

    def check(self, value, label=None):
        """``value`` as a float (an int if ``integer``) inside the range; ValueError otherwise,
        one line naming ``label`` (default: the flag)."""
        label = label or self.flag
        if isinstance(value, bool) or not isinstance(value, (int, float)) and not hasattr(value, "__float__"):
            raise ValueError(f"{label}: not a number ({self.describe()}): {value!r}")
        if isinstance(value, numbers.Integral):  # exact: a float would round a huge int
            v = int(value)
            if not self.low <= v <= self.high:
                side = f"at least {self.low:g}" if v < self.low else f"at most {self.high:g}"
                shown = f"{v:.3g}" if abs(v) > 10**15 else str(v)
                raise ValueError(f"{label}: must be {side} ({self.describe()}), got {shown}")
            return v if self.integer else float(v)
        try:
            v = float(value)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{label}: not a number ({self.describe()}): {value!r}") from None
        if v != v or v in (float("inf"), float("-inf")):
            raise ValueError(f"{label}: not a finite number ({self.describe()}): {value!r}")
        if self.integer and v != int(v):
            raise ValueError(f"{label}: not a whole number ({self.describe()}): {value!r}")
        if v < self.low:
            raise ValueError(f"{label}: must be at least {self.low:g} ({self.describe()}), got {value!r}")
        if v > self.high:
            raise ValueError(f"{label}: must be at most {self.high:g} ({self.describe()}), got {value!r}")
        return int(v) if self.integer else v

    def parse(self, text):
        """The value of a command-line argument (argparse's ``type``: it names the flag)."""
        import argparse

        try:
            number = int(text) if self.integer else float(text)
        except ValueError:
            try:
                number = float(text)  # '1e3' for a whole number, or a clear 'not a whole number'
            except ValueError:
                raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        try:
            return self.check(number, label="value")
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc).split(": ", 1)[1]) from None

    def prop(self) -> dict:
        """min/max for a bpy property (Blender clamps to them)."""
        return {"min": self.low, "max": self.high}


RANGES = {
    r.name: r
    for r in (
        # the edit's sliders
        Range("strength", 0.0, MAX_ENERGY_SCALE, flag="--alpha-scale"),
        Range("colour", 0.0, MAX_ENERGY_SCALE, flag="--alpha"),
        Range("grazing_boost", 0.0, MAX_ENERGY_SCALE),
        Range("mu_slope", *MU_SLOPE_RANGE, flag="--mu"),
        Range("sigma2", *SIGMA2_RANGE),
        Range("roughness", *ROUGHNESS_RANGE, flag="--roughness"),
        Range("correlation_a", -MAX_CORRELATION_A, MAX_CORRELATION_A),
        # the edit engine's other numbers (core/edit), named as in its functions
        Range("albedo_limit", 1e-6, MAX_ENERGY_SCALE, flag="limit"),  # scale_to_albedo's target
        Range("region_grid", 2, 1001, integer=True, flag="n_mu"),  # reachable_region's grid
        # analysis
        Range("elevations", 1, MAX_ELEVATIONS, integer=True),
        Range("max_elevation", 0.0, 89.99),  # [0, 90): the view at 90 deg sees nothing
        Range("max_order", 0, MAX_ORDER, integer=True),
        Range("jobs", 1, MAX_JOBS, integer=True),
        # preview and render
        Range("size", 1, MAX_RENDER_SIZE, integer=True),
        Range("samples", 1, MAX_SAMPLES, integer=True),
        Range("lobe_samples", 1, MAX_LOBE_SAMPLES, integer=True),
        Range("bake_samples", 1, MAX_BAKE_SAMPLES, integer=True),
        # the render engine's own parameters (core/preview), named as in its functions
        Range("diameter", 2, MAX_RENDER_SIZE, integer=True, flag="diameter"),
        Range("light_samples", 0, MAX_BAKE_SAMPLES, integer=True, flag="light_samples"),
        Range("spp", 0, MAX_REFERENCE_SAMPLES, integer=True, flag="spp"),
        Range("diffuse_grid", 1, 64, integer=True, flag="diffuse_grid"),
        Range("seed", 0, MAX_SEED, integer=True, flag="seed"),
        Range("share", 0.0, 1.0, flag="share"),  # a sampling strategy's share of the samples
        Range("image_side", 1, MAX_IMAGE_SIDE, integer=True, flag="width"),  # of an image or a map
        Range("spheres", 1, MAX_SPHERES, integer=True, flag="count"),
        Range("fill", 0.1, 1.0, flag="fill"),  # a sphere's share of its cell
        Range("light_clusters", 1, 4096, integer=True, flag="count"),
        Range("bake_cache_items", 1, BAKE_CACHE_MAX_ENTRIES, integer=True, flag="max_items"),  # bakes in memory
        Range("bake_cache_files", 1, BAKE_CACHE_MAX_ENTRIES, integer=True, flag="max_files"),  # and on disk
        Range("bake_cache_bytes", 1, BAKE_CACHE_MAX_BYTES, integer=True, flag="max_bytes"),
        Range("contrast", 1e-3, 1e6, flag="contrast"),  # a map's clamp, in multiples of its mean luminance
        Range("chunk", 1, 1 << 20, integer=True, flag="chunk"),  # directions per block of a sum
        Range("sampler_rows", 1, MAX_ELEVATIONS, integer=True, flag="n_rows"),  # HalfVectorSampler
        Range("sampler_rings", 1, 1024, integer=True, flag="n_rings"),
        Range("sampler_sub", 1, 64, integer=True, flag="sub"),  # quadrature points per ring, each way
        # the engine's other counts: the integrators, the model, the artist's material
        Range("stride", 1, MAX_ELEVATIONS, integer=True, flag="stride"),  # every stride-th view
        Range("iterations", 1, 1000, integer=True, flag="iters"),  # the truncated-Gaussian solve (40)
        Range("mc_samples", 1, 1 << 32, integer=True, flag="n_samples"),  # Monte Carlo profiles
        Range("rule_lines", 1, 16384, integer=True, flag="n_phi"),  # a slice rule's rays and panels
        Range("gauss_nodes", 1, 32, integer=True, flag="n_gauss"),  # Gauss nodes per panel
        Range("rule_probes", 2, 1 << 16, integer=True, flag="n_probe"),  # cell probes per strip line
        Range("fade_angle", 0.0, 90.0, flag="fade_from"),  # where the rays hand over to the strips, deg
        Range("lobes", 1, 16, integer=True, flag="n_lobes"),  # the artist's material's lobes (5)
        Range("lookup_texels", 1, MAX_ELEVATIONS, integer=True, flag="n_views"),  # its lookup (18)
        Range("near_mirror_deg", 1e-3, 90.0, flag="theta_h_max_deg"),  # rings about the normal (0.3)
    )
}


def check(name, value, label=None):
    """``value`` checked against the declared range of input ``name`` (see RANGES)."""
    return RANGES[name].check(value, label)


def check_int(value, name, low, high):
    """``value`` as an int in [low, high]; ValueError naming ``name`` otherwise (the same
    checks and one-line messages as a declared range: not a number, not whole, outside)."""
    return Range(name, low, high, integer=True).check(value, label=name)


def check_float(value, name, low, high):
    """``value`` as a finite float in [low, high]; ValueError naming ``name`` otherwise."""
    return Range(name, low, high).check(value, label=name)


# The engine's names for the edit's sliders (core.edit.EditTargets' fields): its errors name
# the parameter a caller passed, where the command line names its flag and the panel its slider.
TARGET_FIELDS = {
    n: n for n in ("strength", "colour", "grazing_boost", "mu_slope", "sigma2", "roughness", "correlation_a")
}


def check_targets(targets, labels=None):
    """An edit's slider values (core.edit.EditTargets) inside their declared ranges; the
    first one outside raises ValueError naming it: by ``labels[name]`` (the panel's slider
    names), else by its command-line flag."""
    labels = labels or {}

    def one(name, value):
        check(name, value, labels.get(name))

    one("strength", targets.strength)
    colour = tuple(targets.colour)
    if len(colour) != 3:
        raise ValueError(f"{labels.get('colour', '--alpha')}: expected three numbers R,G,B, got {len(colour)}")
    for v in colour:
        one("colour", v)
    one("grazing_boost", targets.grazing_boost)
    for name in ("mu_slope", "sigma2", "roughness", "correlation_a"):
        if getattr(targets, name, None) is not None:
            one(name, getattr(targets, name))
    return targets
