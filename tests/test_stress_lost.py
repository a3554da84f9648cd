"""Stress: nothing is lost (issue 16, SPEC §7), engine and command line.

One test (or a few) per class of the issue: outputs over inputs, non-regular outputs,
deletions of what the product did not create, images that would crash Blender, damaged
caches and bad maps, hangs and unbounded sizes, tracebacks, name collisions, leftovers.
Each case hashes its inputs before and after and looks for leftovers; every subprocess has
a timeout, so a hang fails the test instead of stalling the suite.
"""

import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

from _stress import ROOT, assert_one_line_error, build_operator_in_memory, exr_bytes, run_cli, sha256

pytestmark = pytest.mark.stress

ENV_CAT = "nothing lost: 4 images that would crash Blender"


@pytest.fixture(scope="module")
def gold(tmp_path_factory):
    import samples

    folder = tmp_path_factory.mktemp("inputs")
    path = folder / "gold.binary"
    shutil.copy(samples.sample_path("gold"), path)
    return path


@pytest.fixture(scope="module")
def gold_json(gold, tmp_path_factory):
    out = tmp_path_factory.mktemp("prof") / "gold.json"
    res = run_cli("profiles", gold, "--out", out, "--elevations", "12")
    assert res.returncode == 0, res.stderr
    return out


def _need_bpy():
    # render runs in a subprocess: only check that the module exists (importing it here would
    # load Blender into the test process outside the session's `blender` fixture)
    import importlib.util

    if importlib.util.find_spec("bpy") is None:
        pytest.skip("the bpy module is not installed")


def _files(folder):
    return sorted(os.path.relpath(os.path.join(d, f), folder) for d, _, fs in os.walk(folder) for f in fs)


# --- 1. outputs that destroy inputs ---------------------------------------------------------


def test_no_command_writes_over_its_inputs(gold, gold_json, tmp_path, stress_log):
    src = tmp_path / "in.binary"
    shutil.copy(gold, src)
    js = tmp_path / "p.json"
    shutil.copy(gold_json, js)
    env = tmp_path / "sky.exr"
    env.write_bytes(exr_bytes(64, 32))
    os.symlink(src, tmp_path / "link.json")
    os.link(src, tmp_path / "hard.png")
    before = {p: sha256(p) for p in (src, js, env)}
    cases = [
        ("profiles --out in", ["profiles", src, "--out", src]),
        ("profiles --plot in", ["profiles", src, "--out", tmp_path / "o.json", "--plot", src]),
        ("profiles --out symlink to in", ["profiles", src, "--out", tmp_path / "link.json"]),
        (
            "profiles --plot hard link to in",
            ["profiles", src, "--out", tmp_path / "o.json", "--plot", tmp_path / "hard.png"],
        ),
        ("fit --out a profiles input", ["fit", js, "--out", js]),
        ("fit --out a MERL input", ["fit", src, "--out", src]),
        ("edit --out in", ["edit", src, "--out", src, "--alpha-scale", "0.5"]),
        ("edit --out hard link", ["edit", src, "--out", tmp_path / "hard.png", "--alpha-scale", "0.5"]),
        ("render --out its --env", ["render", src, "--env", env, "--out", tmp_path / "sky.exr"]),
        ("render --out a hard link to its table", ["render", src, "--out", tmp_path / "hard.png"]),
    ]
    for case, args in cases:
        res = run_cli(*args, timeout=120)
        assert_one_line_error(res, "refusing to overwrite the input")
        stress_log.record("nothing lost: 1 outputs over inputs", "error", case)
    assert {p: sha256(p) for p in before} == before
    assert not (tmp_path / "o.json").exists()
    assert [f for f in os.listdir(tmp_path) if f.startswith(".tmp")] == []


def test_the_engine_guard_refuses_inputs_of_the_run_through_any_writer(gold, tmp_path, stress_log):
    from addon.core.file.atomic import atomic_path
    from addon.core.file.merl import read_merl
    from addon.core.file.safeio import UnsafePath, run_scope

    src = tmp_path / "in.binary"
    shutil.copy(gold, src)
    digest = sha256(src)
    with run_scope():
        read_merl(src)  # an input of this run from now on
        with pytest.raises(UnsafePath, match="overwrite the input"):
            with atomic_path(src, ".json") as tmp, open(tmp, "w") as fh:
                fh.write("{}")
    # Outside the run the same path is an ordinary output again: the scope is what ties them.
    other = tmp_path / "copy.binary"
    shutil.copy(gold, other)
    with run_scope():
        with pytest.raises(UnsafePath):
            with atomic_path(other, inputs=[src, other]) as tmp:
                pass
    assert sha256(src) == digest
    assert sorted(os.listdir(tmp_path)) == ["copy.binary", "in.binary"]
    stress_log.record("nothing lost: 1 outputs over inputs", "error", "atomic_path over a registered input")


# --- 2. replacing what is not a regular file ----------------------------------------------------


def test_devices_fifos_and_folders_are_never_replaced(gold, gold_json, tmp_path, stress_log):
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    folder = tmp_path / "dir.json"
    folder.mkdir()
    png_fifo = tmp_path / "pipe.png"
    os.mkfifo(png_fifo)
    png_dir = tmp_path / "dir.exr"
    png_dir.mkdir()
    targets = {"FIFO": fifo, "/dev/null": "/dev/null", "folder": folder}
    for kind, out in targets.items():
        for cmd in (["profiles", gold, "--elevations", "4"], ["fit", gold_json], ["edit", gold, "--alpha-scale", "2"]):
            res = run_cli(*cmd, "--out", out, timeout=120)
            assert_one_line_error(res, "not a regular file")
            stress_log.record("nothing lost: 2 non-regular outputs", "error", f"{cmd[0]} --out {kind}")
    for kind, out in {"FIFO": png_fifo, "folder": png_dir}.items():
        res = run_cli("render", gold, "--out", out, timeout=120)
        assert_one_line_error(res, "not a regular file")
        stress_log.record("nothing lost: 2 non-regular outputs", "error", f"render --out {kind}")
    png_fifo.unlink()
    png_dir.rmdir()
    res = run_cli("analyze", gold, "--out", fifo, "--no-plots", timeout=120)
    assert_one_line_error(res, "not a folder")
    stress_log.record("nothing lost: 2 non-regular outputs", "error", "analyze --out FIFO")
    assert os.path.exists("/dev/null") and os.stat("/dev/null").st_rdev != 0
    assert folder.is_dir() and list(folder.iterdir()) == []
    import stat

    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert sorted(os.listdir(tmp_path)) == ["dir.json", "pipe.json"]


# --- 3. deleting what the tool did not create ---------------------------------------------------


def test_files_named_like_temporaries_are_never_deleted(tmp_path, stress_log):
    from addon.core.file.atomic import atomic_path, sweep_pending

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    user = {f".tmp-{dead.pid}-notes.json": b"mine", f".tmp-brdfm-{dead.pid}.binary": b"also mine", ".tmp-1-x": b"old"}
    for name, data in user.items():
        (tmp_path / name).write_bytes(data)
    with atomic_path(tmp_path / "out.json") as tmp, open(tmp, "w") as fh:
        fh.write("{}")
    sweep_pending()
    for name, data in user.items():
        assert (tmp_path / name).read_bytes() == data
        stress_log.record("nothing lost: 3 no foreign deletions", "valid", f"user file {name[:12]}... kept")


def test_operator_sweep_removes_only_marked_folders(tmp_path, stress_log):
    from addon.core.file.atomic import MARKER
    from addon.core.profiles.integrate import _MEMO, _OPERATOR_PREFIX, OPERATOR_VERSION, get_operator

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    foreign = [
        "operator-0123456789abcdef0123",
        f"operator-v{OPERATOR_VERSION - 1}-0123456789abcdef0123",
        f".tmp-{dead.pid}-op-killed",
        f"{_OPERATOR_PREFIX}0123456789abcdef0123",
    ]
    ours_old = f"operator-v{OPERATOR_VERSION - 1}s-0123456789abcdef0123"
    for name in foreign + [ours_old]:
        (tmp_path / name).mkdir()
        (tmp_path / name / "weights.npy").write_bytes(b"x")
    (tmp_path / ours_old / MARKER).write_text("created by BRDF Moments")
    _MEMO.clear()
    get_operator(np.radians([10.0]), cache_dir=str(tmp_path))
    left = set(os.listdir(tmp_path))
    assert set(foreign) <= left  # unmarked: not provably ours, never deleted
    assert ours_old not in left  # marked and of another version: swept
    assert all((tmp_path / n / "weights.npy").read_bytes() == b"x" for n in foreign)
    for n in foreign:
        stress_log.record("nothing lost: 3 no foreign deletions", "valid", f"unmarked {n[:20]} kept")
    stress_log.record("nothing lost: 3 no foreign deletions", "valid", "marked old-version operator swept")
    _MEMO.clear()


def test_a_killed_writer_temp_is_removed_only_while_it_is_the_same_file(tmp_path, stress_log):
    # The journal records the inode: a temp name reused by someone else's file is left alone.
    code = (
        "import os, sys, time\nsys.path.insert(0, sys.argv[1])\nfrom addon.core.file.atomic import atomic_path\n"
        "with atomic_path(sys.argv[2]) as tmp:\n    print(tmp, flush=True)\n    time.sleep(600)\n"
    )
    for replaced in (False, True):
        child = subprocess.Popen(
            [sys.executable, "-c", code, ROOT, str(tmp_path / f"o{int(replaced)}.txt")],
            stdout=subprocess.PIPE,
            text=True,
        )
        tmp = child.stdout.readline().strip()
        child.kill()
        child.wait(timeout=30)
        child.stdout.close()
        assert os.path.exists(tmp)
        if replaced:
            # Ours moved away (so its inode stays alive and cannot be reused), another file put
            # at its name: the journal's (device, inode) no longer match, so it is not ours.
            os.rename(tmp, tmp + ".moved")
            with open(tmp, "w") as fh:
                fh.write("someone else's file at the same name")
        from addon.core.file.atomic import sweep_pending

        sweep_pending()
        assert os.path.exists(tmp) == replaced
        stress_log.record(
            "nothing lost: 3 no foreign deletions",
            "valid",
            "same name, other file: kept" if replaced else "killed writer's temp: removed",
        )
        if replaced:
            assert os.path.exists(tmp + ".moved")
            os.unlink(tmp)
            os.unlink(tmp + ".moved")


# --- 4. images that would crash Blender -------------------------------------------------------


def test_image_headers_are_checked_before_decoding(tmp_path, stress_log):
    from addon.core.file.safeio import UnsafePath, check_image_header
    from addon.core.limits import MAX_IMAGE_PIXELS

    big = tmp_path / "huge.exr"
    big.write_bytes(exr_bytes(30000, 15000, body=bytes(2_600_000)))
    cases = {
        "30000x15000 EXR": (big, "30000x15000"),
        "text named .exr": (tmp_path / "text.exr", "not an OpenEXR file"),
        "empty .exr": (tmp_path / "empty.exr", "not an OpenEXR file"),
        "truncated chunk table": (tmp_path / "cut.exr", "truncated"),
        "zero-width EXR": (tmp_path / "zero.exr", "0x"),
        "HDR claiming 100000x100000": (tmp_path / "huge.hdr", "100000x100000"),
        "HDR without resolution": (tmp_path / "nores.hdr", "resolution"),
        "FIFO named .exr": (tmp_path / "fifo.exr", "FIFO"),
        "folder named .exr": (tmp_path / "dir.exr", "directory"),
    }
    (tmp_path / "text.exr").write_text("this is not an image\n")
    (tmp_path / "empty.exr").write_bytes(b"")
    (tmp_path / "cut.exr").write_bytes(exr_bytes(64, 512)[:600])
    (tmp_path / "zero.exr").write_bytes(
        exr_bytes(64, 32).replace(struct.pack("<4i", 0, 0, 63, 31), struct.pack("<4i", 0, 0, -1, 31), 1)
    )
    (tmp_path / "huge.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n" + bytes(64))
    (tmp_path / "nores.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\nnonsense\n")
    os.mkfifo(tmp_path / "fifo.exr")
    (tmp_path / "dir.exr").mkdir()
    for case, (path, fragment) in cases.items():
        with pytest.raises(UnsafePath, match=fragment.replace("(", r"\(")):
            check_image_header(path)
        stress_log.record(ENV_CAT, "error", case)
    # Real headers pass, with their true size: a 64x32 map and a tiny flat RGBE file.
    ok = tmp_path / "ok.exr"
    ok.write_bytes(exr_bytes(64, 32))
    assert check_image_header(ok) == (64, 32)
    hdr = tmp_path / "ok.hdr"
    hdr.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 4\n" + bytes([128, 128, 128, 129]) * 8)
    assert check_image_header(hdr) == (4, 2)
    assert 30000 * 15000 > MAX_IMAGE_PIXELS
    stress_log.record(ENV_CAT, "valid", "real EXR and HDR headers read")


def test_render_refuses_a_huge_map_on_both_paths_without_dying(gold, tmp_path, stress_log):
    _need_bpy()
    big = tmp_path / "huge.exr"
    big.write_bytes(exr_bytes(30000, 15000, body=bytes(2_600_000)))
    for path in ("baked", "osl"):
        res = run_cli(
            "render", gold, "--env", big, "--path", path, "--size", "32", "--out", tmp_path / "o.png", timeout=300
        )
        line = assert_one_line_error(res, "huge.exr", "30000x15000")
        assert res.returncode == 2, line
        stress_log.record(ENV_CAT, "error", f"render --path {path} with a 30000x15000 EXR")
    assert sorted(os.listdir(tmp_path)) == ["huge.exr"]


# --- 5. damaged caches ------------------------------------------------------------------------


def test_an_operator_cache_with_changed_values_is_rebuilt(gold, tmp_path, stress_log):
    from addon.core.profiles import integrate

    views = integrate.default_views(6)
    integrate._MEMO.clear()
    integrate.get_operator(views, cache_dir=str(tmp_path))
    integrate._MEMO.clear()
    (folder,) = [tmp_path / n for n in os.listdir(tmp_path) if n.startswith(integrate._OPERATOR_PREFIX)]
    fresh = build_operator_in_memory(views)
    for case, part, damage in [
        ("weights scaled, same size", "weights.npy", "scale"),
        ("cell index out of range", "cells.npy", "index"),
        ("truncated part", "local.npy", "truncate"),
        ("seal removed", "seal.json", "remove"),
    ]:
        path = folder / part
        if damage == "remove":
            path.unlink()
        elif damage == "truncate":
            with open(path, "r+b") as fh:
                fh.truncate(os.path.getsize(path) // 2)
        else:
            arr = np.load(path)
            if damage == "scale":
                arr[: len(arr) // 2] *= 1.5
                w = np.asarray(fresh.weights)  # the check below would see this damage
                assert not (np.abs(arr - w) <= 1e-5 * np.abs(w).max(axis=0) + 1e-6 * np.abs(w)).all()
            else:
                arr[len(arr) // 3] = 2**30
            with open(path, "r+b") as fh:  # same header, same size: only the values change
                fh.seek(os.path.getsize(path) - arr.nbytes)
                fh.write(arr.tobytes())
        integrate._MEMO.clear()
        op = integrate.get_operator(views, cache_dir=str(tmp_path))
        np.testing.assert_array_equal(np.asarray(op.offsets), np.asarray(fresh.offsets), err_msg=case)
        np.testing.assert_array_equal(np.asarray(op.cells), np.asarray(fresh.cells), err_msg=case)
        for k in ("weights", "local"):
            # float32 sums, some near zero by cancellation: equal to rounding of each column's
            # scale (builds are not bit-identical), while the damage was a factor 1.5
            got, want = np.asarray(getattr(op, k)), np.asarray(getattr(fresh, k))
            scale = np.abs(want).max(axis=0)
            assert (np.abs(got - want) <= 1e-5 * scale + 1e-6 * np.abs(want)).all(), case
        stress_log.record("nothing lost: 5 damaged caches and bad maps", "valid", f"operator: {case}, rebuilt")
        integrate._MEMO.clear()
    assert [n for n in os.listdir(tmp_path) if n.startswith(".tmp")] == []


def test_damaged_bake_cache_entries_are_baked_again(tmp_path, stress_log):
    from addon.core.preview import BakeCache, Environment, ModelBRDF, MomentParams

    env = Environment.constant((0.5, 0.6, 0.7))
    brdf = ModelBRDF(
        MomentParams(
            alpha_b=(0.3, 0.3, 0.3),
            alpha1=(0.0, 0.0, 0.0),
            m1=(0.0, 0.0, 0.0),
            theta0=0.5,
            theta1=1.2,
            mu_slope=-0.9,
            sigma2=0.05,
            kd=(0.1, 0.1, 0.1),
        )
    )
    cache = BakeCache(str(tmp_path))
    rgb, cov, key = cache.get(brdf, env, 16, 8)
    (entry,) = [tmp_path / n for n in os.listdir(tmp_path) if n.startswith("bake-") and n.endswith(".npz")]
    good = entry.read_bytes()
    for case, data in [
        ("truncated", good[: len(good) // 2]),
        ("empty", b""),
        ("flipped bytes", good[:-40] + bytes(40)),
        ("not a zip", b"x" * len(good)),
    ]:
        entry.write_bytes(data)
        fresh = BakeCache(str(tmp_path))
        got, _, _ = fresh.get(brdf, env, 16, 8)
        assert fresh.computed == [key], case  # re-baked, not read
        np.testing.assert_array_equal(got, rgb)
        stress_log.record("nothing lost: 5 damaged caches and bad maps", "valid", f"bake entry {case}: re-baked")
    again = BakeCache(str(tmp_path))
    again.get(brdf, env, 16, 8)
    assert again.computed == []  # the re-written entry verifies


def test_maps_are_validated_the_same_way_for_both_paths(stress_log):
    from addon.core.preview.envmap import check_radiance

    good = np.full((8, 16, 3), 0.5, np.float32)
    check_radiance(good)
    ringing = good.copy()
    ringing[0, 0, 0] = -1e-4  # filtering ringing, as in Blender's own courtyard.exr: accepted
    check_radiance(ringing)
    for case, pix, fragment in [
        ("all NaN", np.full((8, 16, 3), np.nan, np.float32), "NaN"),
        ("one inf", np.where(np.arange(8 * 16 * 3).reshape(8, 16, 3) == 5, np.inf, good), "inf"),
        ("all negative", -good, "no light"),
        ("all zero", 0 * good, "no light"),
        ("half negative", np.concatenate([good[:4], -good[4:]]), "negative"),
        ("1 % negative", np.where(np.arange(8 * 16 * 3).reshape(8, 16, 3) == 7, -2.0, good), "negative"),
    ]:
        with pytest.raises(ValueError, match=fragment):
            check_radiance(pix, "map")
        stress_log.record("nothing lost: 5 damaged caches and bad maps", "error", f"map {case}")


def test_sealed_cache_entries_prove_what_they_hold_and_are_bounded(tmp_path, stress_log):
    from addon.core.file import cachefs

    folder = cachefs.cache_folder(tmp_path / "edits")
    paths = []
    for i in range(6):
        p = os.path.join(folder, f"e{i}.binary")
        with open(p, "wb") as fh:
            fh.write(bytes([i]) * 1000)
        cachefs.write_seal(p)
        os.utime(p + cachefs.SEAL, (1000 + i, 1000 + i))
        paths.append(p)
    user = os.path.join(folder, "user.binary")
    with open(user, "wb") as fh:
        fh.write(b"u" * 5000)
    assert all(cachefs.verified(p) for p in paths)
    with open(paths[0], "r+b") as fh:
        fh.write(b"\xff")
    assert not cachefs.verified(paths[0])
    with pytest.raises(ValueError, match="damaged"):
        cachefs.check_sealed(paths[0])
    stress_log.record("nothing lost: 5 damaged caches and bad maps", "error", "edited table changed after Apply")
    removed = cachefs.prune(folder, 3, 1 << 30, keep=[paths[1]])
    # The three most recently used stay, and the kept one; the user's unsealed file always.
    assert sorted(removed) == ["e0.binary", "e2.binary"]
    assert os.path.exists(user) and os.path.exists(paths[1])
    cachefs.prune(folder, 100, 2500)
    assert os.path.exists(user)
    assert sum(os.path.getsize(p) for p in paths if os.path.exists(p)) <= 2500
    stress_log.record("nothing lost: 6 hangs and bounds", "valid", "edits cache bounded, LRU first")


# --- 6. hangs and unbounded sizes -----------------------------------------------------------


def test_a_fifo_as_input_never_hangs(tmp_path, stress_log):
    fifo = tmp_path / "x.binary"
    os.mkfifo(fifo)
    jfifo = tmp_path / "p.json"
    os.mkfifo(jfifo)
    for case, args in [
        ("profiles", ["profiles", fifo, "--out", tmp_path / "o.json"]),
        ("fit", ["fit", jfifo, "--out", tmp_path / "o.json"]),
        ("fit MERL", ["fit", fifo, "--out", tmp_path / "o.json"]),
        ("edit", ["edit", fifo, "--out", tmp_path / "o.binary"]),
        ("analyze", ["analyze", fifo, "--out", tmp_path / "r", "--no-plots", "--jobs", "1"]),
    ]:
        res = run_cli(*args, timeout=120)
        assert_one_line_error(res, "FIFO", progress="analysing: ")
        stress_log.record("nothing lost: 6 hangs and bounds", "error", f"FIFO input to {case}")
    assert sorted(os.listdir(tmp_path)) == ["p.json", "x.binary"]


def test_every_size_has_a_bound_on_the_command_line(gold, tmp_path, stress_log):
    from addon.core import limits

    cases = [
        (["profiles", gold, "--out", tmp_path / "o.json", "--elevations", "100000"], "at most 360"),
        (["render", gold, "--out", tmp_path / "o.png", "--size", "100000"], f"at most {limits.MAX_RENDER_SIZE}"),
        (["render", gold, "--out", tmp_path / "o.png", "--bake-samples", "99999999999"], "at most"),
        (["render", gold, "--out", tmp_path / "o.png", "--samples", "1000000"], "at most"),
        (["render", gold, "--out", tmp_path / "o.png", "--lobe-samples", "1000000"], "at most"),
        (["analyze", gold, "--out", tmp_path / "r", "--jobs", "100000"], "at most"),
    ]
    for args, fragment in cases:
        res = run_cli(*args, timeout=60)
        assert_one_line_error(res, fragment)
        stress_log.record("nothing lost: 6 hangs and bounds", "error", f"{args[0]} {args[-2]} {args[-1]}")
    assert list(tmp_path.iterdir()) == []


def test_operator_properties_share_the_bounds():
    # The UI's maxima are the same numbers (read from the sources: no bpy needed here).
    from addon.core import limits

    with open(os.path.join(ROOT, "operators", "build_preview.py")) as fh:
        src = fh.read()
    assert "max=MAX_RENDER_SIZE" in src and "max=MAX_SAMPLES" in src
    with open(os.path.join(ROOT, "addon", "blender", "state.py")) as fh:
        assert "max=MAX_RENDER_SIZE" in fh.read()
    assert limits.MAX_RENDER_SIZE == 4096 and limits.check_int(16, "Size", 16, 4096) == 16
    with pytest.raises(ValueError, match="between"):
        limits.check_int(10**12, "Samples", 1, limits.MAX_SAMPLES)


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt(cmd, wait_for, tmp_path, env=None, timeout=60):
    """Start ``python -m addon cmd`` in its own process group, wait until ``wait_for()`` holds,
    send SIGINT to the group (as a terminal's Ctrl-C does) and time the exit."""
    child = subprocess.Popen(
        [sys.executable, "-m", "addon", *map(str, cmd)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env or dict(os.environ),
        start_new_session=True,
        # A terminal's Ctrl-C reaches a program whose SIGINT is at its default; a suite started
        # as a background job of a script inherits it ignored, which the child would keep.
        preexec_fn=_default_sigint,
    )
    t0 = time.monotonic()
    while not wait_for() and child.poll() is None and time.monotonic() - t0 < timeout:
        time.sleep(0.05)
    assert child.poll() is None, ("finished before the interrupt", child.stderr.read())
    os.killpg(child.pid, signal.SIGINT)
    t1 = time.monotonic()
    out, err = child.communicate(timeout=30)
    return child.returncode, err, time.monotonic() - t1


def _pending_entries():
    from addon.core.file.atomic import pending_dir

    try:
        return [n for n in os.listdir(pending_dir()) if n.endswith(".json")]
    except OSError:
        return []


def test_ctrl_c_stops_edit_analyze_and_a_cold_build_promptly(gold, tmp_path, stress_log):
    out = tmp_path / "e.binary"
    cold = tmp_path / "cold-cache"

    def after(seconds):
        t0 = time.monotonic()
        return lambda: time.monotonic() - t0 > seconds

    def building():
        return lambda: cold.exists() and any(n.startswith(".tmp-brdfm-op") for n in os.listdir(cold))

    cases = [
        ("edit", ["edit", gold, "--out", out, "--sigma2", "0.02"], lambda: after(2.5), None),
        # gold plus the 51 RGL networks (decoded on the way): far more than the 2 s before the
        # interrupt even on a quiet machine, where one file alone was done in time.
        (
            "analyze",
            [
                "analyze",
                gold,
                os.path.join(ROOT, "samples", "measured", "nbrdf-rgl-isotropic.npz"),
                "--out",
                tmp_path / "r",
                "--jobs",
                "2",
            ],
            lambda: after(2.0),
            None,
        ),
        (
            "cold build",
            ["profiles", gold, "--out", tmp_path / "p.json"],
            building,
            dict(os.environ, BRDF_MOMENTS_CACHE=str(cold)),
        ),
    ]
    for name, cmd, ready, env_ in cases:
        code, err, took = _interrupt(cmd, ready(), tmp_path, env_)
        lines = err.strip().splitlines()
        assert code == 130, (name, err)
        assert lines and lines[-1].startswith("interrupted") and "Traceback" not in err, (name, err)
        assert took < 10, (name, took)
        stress_log.record("nothing lost: 6 hangs and bounds", "error", f"Ctrl-C during {name} ({took:.1f} s)")
    left = [p for p in _files(tmp_path) if not p.startswith("cold-cache/pending")]
    assert left == [os.path.join("cold-cache", ".brdf-moments")] or left == [], left
    assert not out.exists()
    stress_log.record("nothing lost: 9 leftovers", "valid", "nothing left by interrupted edit/analyze/cold build")


def test_ctrl_c_stops_a_render_promptly_and_leaves_nothing(gold, tmp_path, stress_log):
    _need_bpy()
    import glob
    import tempfile

    from addon.core.profiles.integrate import default_cache_dir

    preview = os.path.join(default_cache_dir(), "preview")

    def temps():  # the cache may be shared with other checkouts: only new temporaries count
        return {n for n in (os.listdir(preview) if os.path.isdir(preview) else []) if n.startswith(".tmp-brdfm-")}

    temps_before = temps()
    scratch_before = set(glob.glob(os.path.join(tempfile.gettempdir(), "brdfm-render-*")))
    out = tmp_path / "r.png"
    t0 = time.monotonic()
    code, err, took = _interrupt(
        ["render", gold, "--path", "baked", "--size", "1024", "--bake-samples", "4096", "--out", out],
        lambda: time.monotonic() - t0 > 12,
        tmp_path,
        timeout=60,
    )
    assert code == 130 and err.strip().splitlines()[-1].startswith("interrupted"), err
    assert took < 10, took
    assert list(tmp_path.iterdir()) == []
    assert set(glob.glob(os.path.join(tempfile.gettempdir(), "brdfm-render-*"))) == scratch_before
    assert temps() <= temps_before
    stress_log.record("nothing lost: 6 hangs and bounds", "error", f"Ctrl-C during render ({took:.1f} s)")


# --- 7. tracebacks instead of one line ----------------------------------------------------------


def test_malformed_profiles_json_is_one_line(gold_json, tmp_path, stress_log):
    good = json.loads(gold_json.read_text())
    ragged = json.loads(gold_json.read_text())
    ragged["avg"]["alpha"] = ragged["avg"]["alpha"][:-1]
    wrong = json.loads(gold_json.read_text())
    wrong["avg"]["mu_theta"][2] = "0.5"
    nested = json.loads(gold_json.read_text())
    nested["kd"] = [[0.1], [0.1], [0.1]]
    cases = {
        "deep nesting": ("[" * 100000 + "]" * 100000, "nested deeper"),
        "nesting 40 levels": ("[" * 40 + "]" * 40, "nested deeper"),
        "lists of different lengths": (json.dumps(ragged), "avg.alpha"),
        "a string where a number belongs": (json.dumps(wrong), "avg.mu_theta[2]"),
        "nested lists for kd": (json.dumps(nested), "kd[0]"),
        "NaN literal": (gold_json.read_text().replace("[", "[NaN, ", 1), "NaN"),
        "top level a list": ("[1, 2, 3]", "expected an object"),
        "missing channel": (json.dumps({k: v for k, v in good.items() if k != "g"}), "'g' is missing"),
        "theta_o as a number": (json.dumps(dict(good, theta_o=1.0)), "theta_o"),
        "huge number": (json.dumps(good).replace(str(good["avg"]["alpha"][0]), "1e999", 1), "alpha[0]"),
        "not UTF-8": (b"\xff\xfe{}", "UTF-8"),
        "true for a value": (json.dumps(good).replace(str(good["avg"]["alpha"][0]), "true", 1), "alpha[0]"),
    }
    for case, (text, fragment) in cases.items():
        path = tmp_path / "bad.json"
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        res = run_cli("fit", path, "--out", tmp_path / "fit.json", timeout=60)
        assert_one_line_error(res, "bad.json", fragment)
        stress_log.record("nothing lost: 7 one line, no traceback", "error", f"fit on {case}")
    assert sorted(os.listdir(tmp_path)) == ["bad.json"]


def test_bad_cache_and_samples_settings_are_one_line(tmp_path, stress_log):
    notadir = tmp_path / "file"
    notadir.write_text("x")
    env = dict(os.environ, BRDF_MOMENTS_SAMPLES=str(notadir))
    res = subprocess.run(
        [sys.executable, "-m", "samples", "gold"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60
    )
    assert_one_line_error(res, "BRDF_MOMENTS_SAMPLES")
    stress_log.record("nothing lost: 7 one line, no traceback", "error", "BRDF_MOMENTS_SAMPLES is a file")


def test_damaged_stored_profiles_are_refused_in_one_line(blender, stress_log):
    import base64

    from addon.blender.state import pack_profiles, unpack_profiles  # the module needs bpy (its property group)
    from addon.core.profiles.compute import Profiles

    n = 4
    ch = {
        c: {
            k: np.linspace(0.1, 0.4, n)
            for k in (
                "alpha",
                "mu_theta",
                "mu_phi",
                "sigma_tt",
                "sigma_tp",
                "sigma_pp",
                "skew_30",
                "skew_21",
                "skew_12",
                "skew_03",
                "kurt_40",
                "kurt_31",
                "kurt_22",
                "kurt_13",
                "kurt_04",
            )
        }
        for c in ("r", "g", "b", "avg")
    }
    text = pack_profiles(Profiles(np.linspace(0, 1, n), np.zeros(3), ch))
    assert unpack_profiles(text).theta_o.shape == (n,)
    raw = np.frombuffer(base64.b64decode(text), "<f8").copy()  # stored as float64 since 2026-12-02
    inf = raw.copy()
    inf[10] = np.inf
    cut = raw[:-3]
    count = raw.copy()
    count[0] = 1e9
    for case, blob in [("inf in a profile", inf), ("truncated", cut), ("absurd view count", count)]:
        with pytest.raises(ValueError, match="damaged"):
            unpack_profiles(base64.b64encode(blob.tobytes()).decode())
        stress_log.record("nothing lost: 7 one line, no traceback", "error", f"stored profiles: {case}")
    with pytest.raises(ValueError, match="damaged"):
        unpack_profiles("not base64 at all!")
    # A .blend from before stores float32: still read, to float32 precision.
    old = base64.b64encode(raw.astype("<f4").tobytes()).decode()
    np.testing.assert_allclose(unpack_profiles(old).theta_o, np.linspace(0, 1, n), rtol=1e-7)
    np.testing.assert_array_equal(unpack_profiles(text).theta_o, np.linspace(0, 1, n))  # float64: exact


# --- 8. name collisions -------------------------------------------------------------------------


def test_distinct_inputs_get_distinct_outputs(gold, tmp_path, stress_log):
    from addon.core.file.names import collisions, distinct_name

    folder = tmp_path / "set"
    folder.mkdir()
    for name in ("a b.binary", "a_b.binary", "a?b.binary"):
        shutil.copy(gold, folder / name)
    res = run_cli("analyze", folder, "--out", tmp_path / "r", "--no-plots", "--jobs", "1", timeout=300)
    assert res.returncode == 0, res.stderr
    files = sorted(os.listdir(tmp_path / "r" / "materials"))
    assert len(files) == 3 and "a_b.json" in files, files
    sources = {json.loads((tmp_path / "r" / "materials" / f).read_text())["material"] for f in files}
    assert sources == {"a b", "a_b", "a?b"}
    stress_log.record("nothing lost: 8 name collisions", "valid", "analyze 'a b', 'a_b', 'a?b': three files")
    names = ["a/b", "a_b", "a\\b", "../a_b", "a_b "]
    outs = [distinct_name(n) for n in names]
    assert len(set(outs)) == len(names) and outs[1] == "a_b"
    stress_log.record("nothing lost: 8 name collisions", "valid", "export names a/b, a_b, ...: distinct")
    assert collisions(["Gold", "gold"]) == [("Gold", "gold")]
    stress_log.record("nothing lost: 8 name collisions", "error", "Gold and gold: refused")


# --- 9. leftovers -------------------------------------------------------------------------------


def test_a_failed_analyze_leaves_nothing(gold, tmp_path, monkeypatch, stress_log):
    import addon.tools.analyze as an

    def boom(*a, **k):
        raise ValueError("plot failed")

    monkeypatch.setattr(an, "_plot_all", boom)
    out = tmp_path / "r"
    with pytest.raises(ValueError, match="plot failed"):
        an.analyze([str(gold)], str(out), workers=1, log=lambda *a: None)
    assert _files(out) == [] if out.exists() else True
    stress_log.record("nothing lost: 9 leftovers", "valid", "analyze failing in its plots: no partial JSON")


def test_a_read_only_folder_names_the_destination(gold, tmp_path, stress_log):
    if os.geteuid() == 0:
        # root ignores permissions: a folder on a read-only mount stands in (mkstemp's error path)
        from addon.core.file import atomic

        folder = tmp_path / "ro"
        folder.mkdir()

        def refuse(*a, **k):
            raise PermissionError(13, "Permission denied", str(folder / ".tmp-brdfm-xyz.json"))

        orig = atomic.tempfile.mkstemp
        atomic.tempfile.mkstemp = refuse
        try:
            with pytest.raises(PermissionError) as info:
                with atomic.atomic_path(folder / "o.json"):
                    pass
        finally:
            atomic.tempfile.mkstemp = orig
        assert info.value.filename == str(folder / "o.json")
    else:
        folder = tmp_path / "ro"
        folder.mkdir()
        folder.chmod(0o555)
        try:
            res = run_cli("profiles", gold, "--out", folder / "o.json", "--elevations", "4", timeout=120)
            line = assert_one_line_error(res, "o.json", "ermission")
            assert ".tmp" not in line
        finally:
            folder.chmod(0o755)
    assert list(folder.iterdir()) == []
    stress_log.record("nothing lost: 9 leftovers", "error", "read-only output folder: names the destination")


def test_an_interrupted_build_removes_its_temporary_folder(tmp_path, stress_log):
    from addon.core.profiles import integrate

    class Stop(Exception):  # as jobs.Cancelled, raised from the progress callback by Esc
        pass

    for exc in (Stop, KeyboardInterrupt):

        def prog(done, total, exc=exc):
            if done == 2:
                raise exc()

        integrate._MEMO.clear()
        with pytest.raises(exc):
            integrate.get_operator(np.radians([0.0, 10.0, 20.0]), cache_dir=str(tmp_path), progress=prog)
        assert [n for n in os.listdir(tmp_path) if n.startswith((".tmp", "operator"))] == []
        stress_log.record("nothing lost: 9 leftovers", "valid", f"cold build stopped by {exc.__name__}")
    integrate._MEMO.clear()


def test_a_render_child_that_dies_is_one_line(gold, tmp_path, monkeypatch, stress_log):
    # Should Blender itself die (a signal), the command still ends in one line and exit 2.
    import argparse

    import addon.tools.render_command as rc

    class Died:
        pid = 2**22 + 12345  # no such process: its journal entries, if any, are swept

        def __init__(self, *a, **k):
            pass

        def wait(self):
            return -11

    monkeypatch.setattr(subprocess, "Popen", Died)

    class Refused(Exception):
        pass

    args = argparse.Namespace(file=str(gold), edited=None, env=None, out=str(tmp_path / "o.png"), argv=["render"])
    with pytest.raises(Refused, match="signal 11"):
        rc.run_in_child(args, Refused)
    assert list(tmp_path.iterdir()) == []
    stress_log.record(ENV_CAT, "error", "render child killed by a signal: one line")


def test_npz_inputs_are_bounded_before_unpacking(tmp_path, stress_log):
    # The generic opener other readers (the Neural-BRDF .npz) build on.
    import zipfile

    from addon.core.file.safeio import UnsafePath, load_npz

    ok = tmp_path / "ok.npz"
    np.savez(ok, w=np.arange(6.0).reshape(2, 3))
    assert load_npz(ok, 1 << 20)["w"].shape == (2, 3)
    bomb = tmp_path / "bomb.npz"
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("w.npy", bytes(64 << 20))  # 64 MB of zeros: a few tens of KB on disk
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, w=np.array([{"a": 1}], dtype=object))
    text = tmp_path / "text.npz"
    text.write_text("not a zip")
    fifo = tmp_path / "fifo.npz"
    os.mkfifo(fifo)
    for case, path, fragment in [
        ("zip bomb", bomb, "unpacks to"),
        ("object array", pickled, "not a valid"),
        ("text", text, "not a valid"),
        ("FIFO", fifo, "FIFO"),
        ("too large", ok, "too large"),
    ]:
        with pytest.raises(UnsafePath, match=fragment):
            load_npz(path, 100 if case == "too large" else 1 << 20)
        stress_log.record("nothing lost: 6 hangs and bounds", "error", f".npz input: {case}")
