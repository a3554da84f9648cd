"""Issue 29's hostile-input classes, each closed by a mechanism and checked as a class:

1. every file the product reads goes through the input opener (``core/file/safeio.open_input``), so
   nothing found by a folder walk can hang it (a FIFO, a link to one);
2. every numeric input has a declared finite range (``core/limits.RANGES``): the command line's
   flags, the extension's properties and the engine's entry points refuse anything outside it
   with one line naming the input;
3. every cache the product writes is sealed, and a failed seal means rebuild: the tabulated
   samples and the compiled OSL shaders too.
"""

import ast
import os
import shutil
import subprocess
import sys

import pytest

from _stress import ROOT, assert_one_line_error, run_cli, sha256

pytestmark = pytest.mark.stress

OPENER = "nothing lost: 10 every read through the opener"
RANGES_CAT = "nothing lost: 11 every number in a declared range"
SEALS = "nothing lost: 12 every cache sealed"

# --- 1. the opener ------------------------------------------------------------------------------

# Reads that do not go through safeio, each with the reason it may not. Keyed by file and the
# call's text; anything else the scan finds fails the test (a new read must use the opener).
READ_ALLOWED = {
    # the opener itself, and readers of bytes it already read
    ("addon/core/file/safeio.py", "zipfile.ZipFile(io.BytesIO(data))"),
    ("addon/core/file/safeio.py", "np.load(io.BytesIO(data), allow_pickle=False)"),
    ("addon/core/file/nbrdf.py", "np.load(io.BytesIO(data), allow_pickle=False)"),
    ("addon/core/preview/cache.py", "np.load(io.BytesIO(data))"),
    # h5py opens by name: open_input checked it is a regular file within the bound just before
    ("addon/core/file/nbrdf.py", "h5py.File(path, 'r')"),
    # the operator's parts, memory-mapped by name after open_input read every byte for the CRC
    ("addon/core/profiles/integrate.py", "np.load(os.path.join(folder, 'theta_o.npy'))"),
    ("addon/core/profiles/integrate.py", "np.load(os.path.join(folder, 'offsets.npy'))"),
    ("addon/core/profiles/integrate.py", "np.load(os.path.join(folder, f'{k}.npy'), mmap_mode='r')"),
    # a raw part the build itself just wrote into its own fresh temporary folder
    ("addon/core/profiles/integrate.py", "open(src, 'rb')"),
    # the kernel's files
    ("addon/core/edit/blas.py", "open('/proc/self/maps')"),
    ("addon/core/file/atomic.py", "open(f'/proc/{pid}/stat', 'rb')"),
}
# Benchmarks read their own outputs and caches; they are not shipped and take no user input.
SCAN_SKIP = ("addon/tools/bench",)
READERS = ("open", "io.open", "np.load", "numpy.load", "np.fromfile", "h5py.File", "OpenEXR.File", "zipfile.ZipFile")


def _reads(path):
    tree = ast.parse(open(path, encoding="utf-8").read())
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = ast.unparse(node.func)
        if name not in READERS:
            continue
        if name in ("open", "io.open"):
            mode = ast.unparse(node.args[1]) if len(node.args) > 1 else ""
            mode = next((ast.unparse(k.value) for k in node.keywords if k.arg == "mode"), mode)
            if any(c in mode for c in "wax"):
                continue  # a write: atomic_path and the output guard are checked elsewhere
        yield ast.unparse(node)


def test_every_read_of_the_product_goes_through_the_opener(stress_log):
    found = set()
    for top in ("addon", "operators", "samples"):
        for base, _dirs, files in os.walk(os.path.join(ROOT, top)):
            for f in files:
                rel = os.path.relpath(os.path.join(base, f), ROOT)
                if f.endswith(".py") and not rel.startswith(SCAN_SKIP):
                    found.update((rel, call) for call in _reads(os.path.join(ROOT, rel)))
    unexpected = sorted(found - READ_ALLOWED)
    assert not unexpected, f"reads that bypass core/file/safeio.open_input: {unexpected}"
    assert not READ_ALLOWED - found, f"allow-list entries no longer in the code: {sorted(READ_ALLOWED - found)}"
    stress_log.record(OPENER, "valid", f"source scan: {len(found)} allowed direct reads, none other")


@pytest.fixture
def fifo_folder(tmp_path, sample_table):
    import samples

    folder = tmp_path / "set"
    folder.mkdir()
    shutil.copy(samples.sample_path("ggx_glossy"), folder / "good.binary")
    return folder


@pytest.mark.parametrize("kind", ["fifo .binary", "link to a fifo", "fifo .npy weights", "fifo in a subfolder"])
def test_a_folder_walk_never_opens_a_fifo(fifo_folder, tmp_path, kind, stress_log):
    if kind == "fifo .binary":
        os.mkfifo(fifo_folder / "pipe.binary")
        bad = "pipe.binary"
    elif kind == "link to a fifo":
        os.mkfifo(tmp_path / "elsewhere")
        os.symlink(tmp_path / "elsewhere", fifo_folder / "link.binary")
        bad = "link.binary"
    elif kind == "fifo .npy weights":
        (fifo_folder / "good.binary").unlink()
        os.mkfifo(fifo_folder / "m_fc1.npy")
        bad = "m_fc1.npy"
    else:
        (fifo_folder / "sub.binary").mkdir()
        os.mkfifo(fifo_folder / "sub.binary" / "x_fc1.npy")
        bad = "sub.binary"
    res = run_cli("analyze", fifo_folder, "--out", tmp_path / "out", "--jobs", "1", "--no-plots", timeout=240)
    assert res.returncode == 2, (res.stdout, res.stderr)
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert any(bad in ln for ln in errors) and "Traceback" not in res.stderr, res.stderr
    stress_log.record(OPENER, "error", f"analyze FOLDER with a {kind}")


def _in_child(code, timeout=120, **env):
    return subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=dict(os.environ, **{k: str(v) for k, v in env.items()}),
    )


def test_fifos_in_the_caches_walks_never_hang(tmp_path, stress_log):
    """The journal of temporaries and an operator folder are walked by every run: a FIFO
    planted in either is skipped, never opened (each run in a child with a timeout)."""
    from addon.core.file.atomic import MARKER

    cache = tmp_path / "cache"
    pending = cache / "pending"
    pending.mkdir(parents=True)
    (cache / MARKER).write_text("x")
    (pending / MARKER).write_text("x")
    os.mkfifo(pending / "1-1-0123456789abcdef.json")  # named like a dead writer's entry
    res = _in_child(
        "from addon.core.file.atomic import sweep_pending; print(sweep_pending())", BRDF_MOMENTS_CACHE=cache
    )
    assert res.returncode == 0 and res.stdout.strip() == "[]", res.stderr
    stress_log.record(OPENER, "valid", "FIFO in the journal of temporaries: skipped")

    code = (
        "import numpy as np\n"
        "from addon.core.profiles.integrate import get_operator, _operator_key, _OPERATOR_PREFIX, RuleParams\n"
        "import os, sys\n"
        "views = np.radians([45.0])\n"
        "folder = os.path.join(sys.argv[1] if len(sys.argv) > 1 else os.environ['BRDF_MOMENTS_CACHE'],"
        " _OPERATOR_PREFIX + _operator_key(views, RuleParams()))\n"
        "op = get_operator(views, memo=False)\n"
        "print(len(op.theta_o))\n"
    )
    res = _in_child(code, BRDF_MOMENTS_CACHE=cache)  # builds a one-view operator into the cache
    assert res.returncode == 0, res.stderr
    (folder,) = [p for p in cache.iterdir() if p.name.startswith("operator-")]
    (folder / "seal.json").unlink()
    os.mkfifo(folder / "seal.json")
    res = _in_child(code, BRDF_MOMENTS_CACHE=cache)
    assert res.returncode == 0 and res.stdout.strip() == "1", res.stderr
    stress_log.record(OPENER, "valid", "FIFO as an operator's seal: not opened, operator rebuilt")


# --- 2. declared ranges -------------------------------------------------------------------------


def _numeric_actions():
    from addon.core.limits import RANGES
    from addon.tools.cli import build_parser

    parser = build_parser()
    for sub in parser._subparsers._group_actions[0].choices.values():
        for action in sub._actions:
            if action.option_strings and action.type is not None:
                yield sub.prog, action, RANGES


def test_every_numeric_flag_has_a_declared_range(stress_log):
    """No flag parses a bare int or float: each numeric one goes through a limits.Range."""
    seen = 0
    for prog, action, ranges in _numeric_actions():
        t = action.type
        assert t not in (int, float), f"{prog} {action.option_strings[0]}: a bare {t.__name__}"
        owner = getattr(t, "__self__", None)
        if owner is not None:
            assert owner in ranges.values(), (prog, action.option_strings)
            assert owner.flag == action.option_strings[0], (owner.flag, action.option_strings)
            seen += 1
    assert seen >= 11
    stress_log.record(RANGES_CAT, "valid", f"{seen} numeric flags, each with a declared range")


EDIT_FLAGS = ["--alpha-scale", "--grazing-boost", "--mu", "--sigma2"]


@pytest.mark.parametrize("flag", EDIT_FLAGS + ["--alpha"])
@pytest.mark.parametrize("value", ["1e308", "-1e308", "inf", "nan"])
def test_huge_numbers_on_the_command_line_are_one_line_errors(flag, value, tmp_path, stress_log):
    out = tmp_path / "e.binary"
    arg = f"1,{value},1" if flag == "--alpha" else value
    res = run_cli("edit", os.path.join(ROOT, "samples", "nonexistent.binary"), "--out", out, flag + "=" + arg)
    line = assert_one_line_error(res, flag)
    assert "finite" in line or "between" in line, line  # "at most 16 (between 0 and 16)"
    assert not out.exists()
    stress_log.record(RANGES_CAT, "error", f"edit {flag} {value}")


@pytest.mark.parametrize(
    "cmd, flag",
    [
        (["profiles", "x.binary", "--out", "o.json", "--elevations"], "--elevations"),
        (["profiles", "x.binary", "--out", "o.json", "--max-elevation"], "--max-elevation"),
        (["profiles", "x.binary", "--out", "o.json", "--max-order"], "--max-order"),
        (["analyze", "x.binary", "--out", "o", "--jobs"], "--jobs"),
        (["render", "x.binary", "--out", "o.png", "--size"], "--size"),
        (["render", "x.binary", "--out", "o.png", "--samples"], "--samples"),
        (["render", "x.binary", "--out", "o.png", "--lobe-samples"], "--lobe-samples"),
        (["render", "x.binary", "--out", "o.png", "--bake-samples"], "--bake-samples"),
    ],
)
def test_every_other_numeric_flag_refuses_huge_values(cmd, flag, tmp_path, stress_log):
    for value in ("1e308", "-1e308", "99999999999999999999999"):
        res = run_cli(*cmd, value, cwd=tmp_path)
        assert_one_line_error(res, flag)
    stress_log.record(RANGES_CAT, "error", f"{cmd[0]} {flag} 1e308, -1e308, 1e23")


def test_the_engine_entry_points_check_the_same_ranges(sample_table, stress_log):
    from addon.core.edit import EditTargets
    from addon.core.limits import check_targets
    from addon.core.profiles.compute import compute_profiles
    from addon.core.profiles.integrate import default_views

    for field, value in (
        ("grazing_boost", 1e308),
        ("strength", -1.0),
        ("colour", (1.0, float("inf"), 1.0)),
        ("mu_slope", -1e308),
        ("sigma2", float("nan")),
    ):
        with pytest.raises(ValueError) as err:
            check_targets(EditTargets(**{field: value}))
        assert len(str(err.value).splitlines()) == 1
        stress_log.record(RANGES_CAT, "error", f"EditTargets({field}={value})")
    check_targets(EditTargets(strength=16.0, grazing_boost=0.0, mu_slope=-2.0, sigma2=0.8))  # the edges are in
    for call in (
        lambda: default_views(10**9),
        lambda: default_views(90, 1e308),
        lambda: compute_profiles(sample_table("ggx_glossy"), [0.1] * 100_000),
        lambda: compute_profiles(sample_table("ggx_glossy"), [0.1, float("nan")]),
        lambda: compute_profiles(sample_table("ggx_glossy"), max_order=10**12),
    ):
        with pytest.raises(ValueError) as err:
            call()
        assert len(str(err.value).splitlines()) == 1
        stress_log.record(RANGES_CAT, "error", f"engine: {str(err.value)[:60]}")


def _render_calls():
    """(public render function with one numeric parameter set, the parameter's name): the
    preview engine's sizes, sample counts, seeds and shares (core/preview)."""
    from addon.core.preview import (
        BakeCache,
        Environment,
        ModelBRDF,
        MomentParams,
        bake_sphere,
        reference_sphere,
        render_baked,
        render_reference,
        sphere_layout,
    )

    third = (0.1, 0.1, 0.1)
    params = MomentParams(third, (0.2, 0.2, 0.2), (0.0, 0.0, 0.0), 0.785, 1.31, -0.5, 0.05)
    brdf, env, lay = ModelBRDF(params), Environment.constant((1.0, 1.0, 1.0)), sphere_layout(16, 16, 1)
    return [
        (lambda v: bake_sphere(brdf, env, v), "diameter"),
        (lambda v: bake_sphere(brdf, env, 8, lobe_samples=v), "lobe_samples"),
        (lambda v: bake_sphere(brdf, env, 8, 4, light_samples=v), "light_samples"),
        (lambda v: bake_sphere(brdf, env, 8, 4, seed=v), "seed"),
        (lambda v: bake_sphere(brdf, env, 8, 4, cosine_share=v), "cosine_share"),
        (lambda v: reference_sphere(brdf, env, v), "diameter"),
        (lambda v: reference_sphere(brdf, env, 8, spp=v), "spp"),
        (lambda v: reference_sphere(brdf, env, 8, 4, diffuse_grid=v), "diffuse_grid"),
        (lambda v: reference_sphere(brdf, env, 8, 4, shares=(0.5, v, 0.5)), "shares"),
        (lambda v: render_reference(lay, [brdf], env, spp=v), "spp"),
        (lambda v: render_reference(lay, [brdf], env, 4, seed=v), "seed"),
        (lambda v: render_baked(lay, [brdf], env, lobe_samples=v), "lobe_samples"),
        (lambda v: sphere_layout(v), "width"),
        (lambda v: sphere_layout(64, v), "height"),
        (lambda v: sphere_layout(64, 64, v), "count"),
        (lambda v: sphere_layout(64, 64, 1, v), "fill"),
        (lambda v: BakeCache().get(brdf, env, v), "diameter"),
        (lambda v: BakeCache().get(brdf, env, 8, v), "lobe_samples"),
        (lambda v: Environment.constant((1.0, 1.0, 1.0), width=v), "width"),
        (lambda v: Environment.from_function(lambda d: d * 0 + 1, 8, v), "height"),
        (lambda v: env.irradiance_map(v), "diameter"),
        (lambda v: params.edited(strength=v), "strength"),
        (lambda v: params.edited(sigma2=v), "sigma2"),
    ]


# huge, negative, NaN, inf, not a whole number, a number given as text
HOSTILE = (10**12, 1e308, -1, -1e308, float("nan"), float("inf"), 2.5, "8")


def test_the_render_engine_refuses_numbers_outside_their_declared_ranges(stress_log):
    """bake_sphere, reference_sphere, render_reference/render_baked, sphere_layout, the bake
    cache, the environment's constructors and the model's sliders took any number: a size of
    10^12 tried to allocate it, NaN and 2.5 went through int(). Each refuses it now, one line
    naming the parameter (limits.RANGES), before any work."""
    for call, name in _render_calls():
        for value in HOSTILE:
            if name in ("fill", "cosine_share", "shares", "strength", "sigma2") and value == 2.5:
                value = 17.0  # a share, a fill and the sliders may be fractions: 17 is outside
            if name == "seed" and value == 10**12:
                value = 2**64  # any seed numpy takes is in, up to 2^63 - 1
            with pytest.raises(ValueError) as err:
                call(value)
            msg = str(err.value)
            assert len(msg.splitlines()) == 1 and msg.startswith(name + ":"), (name, value, msg)
        stress_log.record(RANGES_CAT, "error", f"render engine: {name} huge, negative, NaN, inf, 2.5, text")
    # the edges are in (each call returns)
    from addon.core.preview import Environment, sphere_layout

    assert sphere_layout(8, 8, 1, 1.0).diameter == 8
    assert Environment.constant((1, 1, 1), 4, 2).pixels.shape[:2] == (2, 4)


def test_the_edit_engine_refuses_numbers_outside_their_declared_ranges(sample_table, stress_log):
    """The edit's other public numbers: the albedo's view stride, scale_to_albedo's limit, the
    reachable region's grid."""
    from addon.core.edit import directional_albedo, reachable_region, scale_to_albedo
    from addon.core.fits.curves import fit_material
    from addon.core.profiles.compute import compute_profiles
    from addon.core.profiles.integrate import default_views

    table = sample_table("ggx_glossy")
    prof = compute_profiles(table, default_views(4, 80.0))
    fit = fit_material(prof)
    for call, name in (
        (lambda v: directional_albedo(table, prof.theta_o, v), "stride"),
        (lambda v: scale_to_albedo(None, v), "limit"),
        (lambda v: reachable_region(prof, fit, n_mu=v), "n_mu"),
        (lambda v: reachable_region(prof, fit, n_sigma=v), "n_sigma"),
    ):
        for value in (10**12, 1e308, -1, float("nan"), float("inf"), 0, "3"):
            with pytest.raises(ValueError) as err:
                call(value)
            msg = str(err.value)
            assert len(msg.splitlines()) == 1 and msg.startswith(name + ":"), (name, value, msg)
        stress_log.record(RANGES_CAT, "error", f"edit engine: {name} huge, negative, NaN, inf, 0, text")


@pytest.mark.blender
def test_the_sliders_are_held_inside_their_declared_ranges(blender, stress_log):
    """Blender clamps a property to min/max: the declared ranges are the sliders' hard limits."""
    from addon.core.limits import RANGES

    mat = blender.data.materials.new("ranges")
    st = mat.brdf_moments
    for prop, name in (
        ("strength", "strength"),
        ("grazing_boost", "grazing_boost"),
        ("mu_slope", "mu_slope"),
        ("sigma2", "sigma2"),
        ("correlation_a", "correlation_a"),
    ):
        for value, edge in ((1e308, RANGES[name].high), (-1e308, RANGES[name].low)):
            setattr(st, prop, value)
            assert getattr(st, prop) == pytest.approx(edge, rel=1e-6), prop
        stress_log.record(RANGES_CAT, "clamped", f"slider {prop} at +-1e308")
    st.colour = (1e308, 0.5, -1e308)
    assert tuple(st.colour) == pytest.approx((RANGES["colour"].high, 0.5, 0.0))
    blender.data.materials.remove(mat)


# --- 3. seals -----------------------------------------------------------------------------------


@pytest.mark.parametrize("damage", ["truncated", "one byte changed", "seal missing", "emptied"])
def test_a_damaged_sample_table_is_tabulated_again(tmp_path, damage, stress_log):
    """`python -m samples NAME` printed a truncated table's path as good, and `profiles` then
    failed on it. The table is sealed: any damage is a miss, and the table comes back whole,
    equal to a fresh tabulation in another folder."""
    fresh, cache = tmp_path / "fresh", tmp_path / "cache"

    def samples_cli(folder):
        res = subprocess.run(
            [sys.executable, "-m", "samples", "lambertian"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
            env=dict(os.environ, BRDF_MOMENTS_SAMPLES=str(folder)),
        )
        assert res.returncode == 0, res.stderr
        return res.stdout.strip()

    want = sha256(samples_cli(fresh))
    path = samples_cli(cache)
    if damage == "truncated":
        os.truncate(path, os.path.getsize(path) // 2)
    elif damage == "one byte changed":
        with open(path, "r+b") as fh:
            fh.seek(1000)
            b = fh.read(1)
            fh.seek(1000)
            fh.write(bytes([b[0] ^ 0x40]))
    elif damage == "seal missing":  # a table left by an older version: not trusted either
        os.unlink(path + ".seal")
    else:
        os.truncate(path, 0)
    assert samples_cli(cache) == path
    assert sha256(path) == want
    res = run_cli("profiles", path, "--out", tmp_path / "p.json", "--elevations", "4")
    assert res.returncode == 0, res.stderr
    stress_log.record(SEALS, "valid", f"sample table {damage}: tabulated again, equal to a fresh one")


@pytest.mark.blender
@pytest.mark.parametrize("damage", ["truncated", "garbage", "seal missing"])
def test_a_damaged_compiled_shader_is_compiled_again(blender, tmp_path, damage, stress_log):
    """A corrupted .oso in the preview cache made every OSL render fail, on every run."""
    import sys as _sys

    osl = _sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.preview.osl"]
    ok, why = osl.osl_available()
    if not ok:
        pytest.skip(why)
    first = osl.compile_shader("brdf_moments_table", folder=str(tmp_path))
    good = open(first, "rb").read()
    if damage == "truncated":
        os.truncate(first, len(good) // 3)
    elif damage == "garbage":
        with open(first, "wb") as fh:
            fh.write(b"OpenShadingLanguage 1.00\nnot a shader\n")
    else:
        os.unlink(first + ".seal")
        with open(first, "ab") as fh:
            fh.write(b"\n# appended\n")
    again = osl.compile_shader("brdf_moments_table", folder=str(tmp_path))

    def code(raw):  # the compiled shader without oslc's comments (they name its temporary file)
        return [ln for ln in raw.splitlines() if not ln.startswith(b"#")]

    assert again == first and code(open(again, "rb").read()) == code(good)
    from addon.core.file.cachefs import verified

    assert verified(again)
    stress_log.record(SEALS, "valid", f"compiled OSL shader {damage}: compiled again")
