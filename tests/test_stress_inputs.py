"""Stress: fuzzed MERL files through the engine and the command line; no input is ever
modified, no failed or killed writer leaves a half-written output.

Every fuzzed file is made from the bytes of one cached sample (ggx_glossy) in tmp_path.
"""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import zlib

import numpy as np
import pytest

from _stress import (
    ROOT,
    assert_finite_tree,
    assert_one_line_error,
    assert_profiles_sane,
    merl_bytes,
    run_cli,
    sha256,
    stored_of,
)
from addon.core.file.merl import FILE_BYTES, N_CELLS, MerlError, read_merl, write_merl
from addon.core.fits.curves import fit_material
from addon.core.profiles.compute import compute_profiles

pytestmark = pytest.mark.stress


@pytest.fixture(scope="module")
def base_raw():
    import samples

    with open(samples.sample_path("ggx_glossy"), "rb") as fh:
        return fh.read()


@pytest.fixture(scope="module")
def base_profiles(base_raw, tmp_path_factory):
    path = tmp_path_factory.mktemp("base") / "base.binary"
    path.write_bytes(base_raw)
    return compute_profiles(read_merl(path))


def _with(stored_fn):
    def build(raw, rng):
        s = stored_of(raw)
        stored_fn(s, rng)
        return merl_bytes(s)

    return build


def _set(ch, cell, value):
    def fn(s, rng):
        s[ch, cell] = value

    return fn


def _bits(u64):
    return np.array([u64], dtype="<u8").view("<f8")[0]


def _spots(value, n=5):
    def fn(s, rng):
        s.reshape(-1)[rng.choice(s.size, n, replace=False)] = value

    return fn


# (id, category, build(raw, rng) -> bytes, expected fault or None, outcome when it loads)
CASES = [
    # truncated or padded
    ("empty", "truncated or padded", lambda r, g: b"", "too short", None),
    ("5 bytes", "truncated or padded", lambda r, g: r[:5], "too short", None),
    ("header only", "truncated or padded", lambda r, g: r[:12], "truncated", None),
    ("one value", "truncated or padded", lambda r, g: r[:20], "truncated", None),
    ("half", "truncated or padded", lambda r, g: r[: FILE_BYTES // 2], "truncated", None),
    ("minus 1 byte", "truncated or padded", lambda r, g: r[:-1], "truncated", None),
    ("minus 1 value", "truncated or padded", lambda r, g: r[:-8], "truncated", None),
    ("plus 1 byte", "truncated or padded", lambda r, g: r + b"\0", "oversized", None),
    ("plus 1 value", "truncated or padded", lambda r, g: r + r[-8:], "oversized", None),
    ("twice", "truncated or padded", lambda r, g: r + r, "oversized", None),
    # wrong header
    ("90x90x181", "wrong header", lambda r, g: merl_bytes(stored_of(r), (90, 90, 181)), "wrong header", None),
    ("180x90x90", "wrong header", lambda r, g: merl_bytes(stored_of(r), (180, 90, 90)), "wrong header", None),
    (
        "big-endian",
        "wrong header",
        lambda r, g: np.array([90, 90, 180], ">i4").tobytes() + r[12:],
        "wrong header",
        None,
    ),
    ("zeros", "wrong header", lambda r, g: b"\0" * 12 + r[12:], "wrong header", None),
    ("negative", "wrong header", lambda r, g: merl_bytes(stored_of(r), (-90, 90, 180)), "wrong header", None),
    ("1x1x1", "wrong header", lambda r, g: np.array([1, 1, 1], "<i4").tobytes() + r[12:36], "wrong header", None),
    ("text", "wrong header", lambda r, g: b"this is not a BRDF, just some text\n", "wrong header", None),
    # random bytes
    ("random 1", "random bytes", lambda r, g: g.bytes(FILE_BYTES), "wrong header", None),
    ("random 2", "random bytes", lambda r, g: g.bytes(FILE_BYTES), "wrong header", None),
    ("random short", "random bytes", lambda r, g: g.bytes(int(g.integers(13, 4000))), "wrong header", None),
    ("random body 1", "random bytes", lambda r, g: r[:12] + g.bytes(FILE_BYTES - 12), "non-finite", None),
    ("random body 2", "random bytes", lambda r, g: r[:12] + g.bytes(FILE_BYTES - 12), "non-finite", None),
    (
        "random finite body",
        "random bytes",
        lambda r, g: merl_bytes(np.where(g.random((3, N_CELLS)) < 0.05, -1.0, g.random((3, N_CELLS)) * 3000.0)),
        None,
        "valid",
    ),
    # NaN or inf
    ("NaN first cell", "NaN or inf", _with(_set(0, 0, np.nan)), "non-finite", None),
    ("NaN last cell", "NaN or inf", _with(_set(2, N_CELLS - 1, np.nan)), "non-finite", None),
    ("NaN payload", "NaN or inf", _with(_set(1, 777, _bits(0x7FF8000000000001))), "non-finite", None),
    ("signalling NaN", "NaN or inf", _with(_set(1, 778, _bits(0x7FF0000000000001))), "non-finite", None),
    ("negative NaN", "NaN or inf", _with(_set(0, 5, _bits(0xFFF8000000000000))), "non-finite", None),
    ("+inf", "NaN or inf", _with(_set(2, 12345, np.inf)), "non-finite", None),
    ("-inf", "NaN or inf", _with(_set(0, 54321, -np.inf)), "non-finite", None),
    ("scattered NaN", "NaN or inf", _with(_spots(np.nan)), "non-finite", None),
    # all cells missing
    ("all -1", "all cells missing", _with(lambda s, g: s.fill(-1.0)), "no measured cells", None),
    ("all -1e300", "all cells missing", _with(lambda s, g: s.fill(-1e300)), "no measured cells", None),
    ("green missing", "all cells missing", _with(lambda s, g: s[1].fill(-1.0)), None, "clamped"),
    (
        "one cell left",
        "all cells missing",
        _with(lambda s, g: (s.fill(-1.0), s.__setitem__((slice(None), 1234567), 1.0))),
        None,
        "clamped",
    ),
    # all-zero channel
    ("green zero", "all-zero channel", _with(lambda s, g: s[1].__setitem__(s[1] >= 0, 0.0)), None, "clamped"),
    ("all zero", "all-zero channel", _with(lambda s, g: s.__setitem__(s >= 0, 0.0)), None, "clamped"),
    ("all -0.0", "all-zero channel", _with(lambda s, g: s.fill(-0.0)), None, "clamped"),
    # huge values
    ("x 1e12", "1e12 and huge values", _with(lambda s, g: s.__setitem__(s >= 0, s[s >= 0] * 1e12)), None, "valid"),
    ("one 1e12 cell", "1e12 and huge values", _with(_set(0, 1000, 1e12)), None, "valid"),
    (
        "x 1e30",
        "1e12 and huge values",
        _with(lambda s, g: s.__setitem__(s >= 0, s[s >= 0] * 1e30)),
        "above 1e+30",
        None,
    ),
    ("one max double", "1e12 and huge values", _with(_set(1, 99, np.finfo(float).max)), "above 1e+30", None),
    # subnormals
    (
        "scaled to 1e-310",
        "subnormals",
        _with(lambda s, g: s.__setitem__(s >= 0, s[s >= 0] * (1e-310 / s.max()))),
        None,
        "valid",
    ),
    ("sprinkled 5e-324", "subnormals", _with(_spots(5e-324, 1000)), None, "valid"),
    ("all 5e-324", "subnormals", _with(lambda s, g: s.fill(5e-324)), None, "clamped"),
]


def _check_loaded(table, prof, fit, base_profiles, case_id):
    assert_profiles_sane(prof)
    json.dumps(prof.to_json(), allow_nan=False)
    json.dumps(fit, allow_nan=False)
    assert_finite_tree(prof.to_json())
    assert_finite_tree(fit)
    if case_id in ("x 1e12", "scaled to 1e-310"):
        # A scale changes no moment (kd, the minimum, scales too): equal to the original's.
        tol = 1e-5 if case_id != "scaled to 1e-310" else 1e-4
        for k in ("mu_theta", "sigma_tt", "sigma_pp", "skew_30", "kurt_40"):
            np.testing.assert_allclose(prof["avg"][k], base_profiles["avg"][k], rtol=tol, atol=tol, err_msg=k)
    if case_id == "green zero":
        assert np.all(prof["g"]["alpha"] == 0) and np.all(np.isnan(prof["g"]["mu_theta"]))
        assert any("almost no specular energy" in n for n in fit["notes"])
    if case_id in ("all zero", "all -0.0", "all 5e-324", "green missing"):
        assert fit["mu_slope"] is None and any("no specular energy" in n for n in fit["notes"])


@pytest.mark.parametrize("case_id, category, build, fault, outcome", CASES, ids=[c[0] for c in CASES])
def test_fuzzed_file_is_refused_clearly_or_analysed_finitely(
    tmp_path, base_raw, base_profiles, stress_log, case_id, category, build, fault, outcome
):
    rng = np.random.default_rng(zlib.crc32(case_id.encode()))
    path = tmp_path / "fuzzed.binary"
    path.write_bytes(build(base_raw, rng))
    digest = sha256(path)
    if fault:
        with pytest.raises(MerlError) as info:
            read_merl(path)
        msg = str(info.value)
        assert str(path) in msg and fault in msg, msg
        assert "\n" not in msg
        stress_log.record(category, "error", f"{case_id}: {info.value.fault}")
    else:
        table = read_merl(path)
        prof = compute_profiles(table)
        fit = fit_material(prof)
        _check_loaded(table, prof, fit, base_profiles, case_id)
        out = tmp_path / "copy.binary"
        write_merl(table, out)
        np.testing.assert_array_equal(read_merl(out).valid, table.valid)
        with pytest.raises(MerlError, match="overwrite the input"):
            write_merl(table, path)
        stress_log.record(category, outcome, case_id)
    assert sha256(path) == digest  # the input is never modified
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".tmp-")]


# --- the command line -------------------------------------------------------------------------

CLI_CASES = [  # (case id from CASES, command)
    ("empty", "profiles"),
    ("minus 1 value", "fit"),
    ("big-endian", "edit"),
    ("random 1", "analyze"),
    ("NaN payload", "profiles"),
    ("-inf", "edit"),
    ("all -1", "fit"),
    ("x 1e30", "profiles"),
]


def _cli_args(command, path, out_dir):
    if command == "profiles":
        return ["profiles", path, "--out", out_dir / "p.json", "--elevations", "4"]
    if command == "fit":
        return ["fit", path, "--out", out_dir / "f.json"]
    if command == "edit":
        return ["edit", path, "--out", out_dir / "e.binary", "--mu", "-0.5"]
    return ["analyze", path, "--out", out_dir / "results", "--no-plots", "--jobs", "1"]


@pytest.mark.parametrize("case_id, command", CLI_CASES)
def test_cli_refuses_a_bad_file_with_one_line_and_writes_nothing(tmp_path, base_raw, stress_log, case_id, command):
    case = next(c for c in CASES if c[0] == case_id)
    rng = np.random.default_rng(zlib.crc32(case_id.encode()))
    inputs = tmp_path / "in"
    inputs.mkdir()
    path = inputs / "broken input.binary"
    path.write_bytes(case[2](base_raw, rng))
    digest = sha256(path)
    out_dir = tmp_path / "out"
    res = run_cli(*_cli_args(command, path, out_dir))
    assert_one_line_error(res, path, case[3], progress="analysing: " if command == "analyze" else None)
    assert sha256(path) == digest
    assert os.listdir(inputs) == ["broken input.binary"]
    # Nothing written, not even a temporary file (analyze may have made its empty folder).
    written = [os.path.join(d, f) for d, _, fs in os.walk(out_dir) for f in fs] if out_dir.exists() else []
    assert written == []
    stress_log.record("command line, bad files", "error", f"{command} on {case_id}")


def test_cli_usage_errors_are_one_line(tmp_path, stress_log):
    for args, fragment in [
        (["edit", "x.binary", "--out", tmp_path / "o.binary", "--sigma2", "nan"], "not a finite"),
        (["profiles", "x.binary", "--out", tmp_path / "o.json", "--elevations", "0"], "at least 1"),
        (["profiles", "x.binary", "--out", tmp_path / "o.json", "--max-elevation", "89.95"], None),
        (["fit"], "required"),
    ]:
        res = run_cli(*args)
        if fragment is None:  # a valid elevation: then the missing file is the fault
            assert_one_line_error(res, "x.binary", "cannot read")
        else:
            assert_one_line_error(res, fragment)
        stress_log.record("command line, bad options", "error", " ".join(map(str, args[:1] + args[-2:])))
    assert list(tmp_path.iterdir()) == []


def test_cli_output_that_is_a_folder_is_named_in_the_error(tmp_path, stress_log):
    import samples

    target = tmp_path / "taken.json"
    target.mkdir()
    res = run_cli("profiles", samples.sample_path("gold"), "--out", target, "--elevations", "2")
    assert_one_line_error(res, target, "directory")
    assert os.listdir(tmp_path) == ["taken.json"] and os.listdir(target) == []
    stress_log.record("command line, bad options", "error", "--out names a folder")


def test_cli_on_degenerate_but_valid_files_exits_cleanly(tmp_path, base_raw, stress_log):
    rng = np.random.default_rng(0)
    for case_id in ("green zero", "green missing"):
        case = next(c for c in CASES if c[0] == case_id)
        path = tmp_path / f"{case_id.replace(' ', '_')}.binary"
        path.write_bytes(case[2](base_raw, rng))
        digest = sha256(path)
        out = tmp_path / f"{path.stem}.json"
        res = run_cli("profiles", path, "--out", out, "--elevations", "6", "--max-elevation", "89.9")
        assert res.returncode == 0, res.stderr
        data = json.loads(out.read_text())  # strict JSON: a NaN would not even parse as "NaN" here
        assert_finite_tree(data)
        res = run_cli("fit", path, "--out", tmp_path / "fit.json")
        assert res.returncode == 0, res.stderr
        assert_finite_tree(json.loads((tmp_path / "fit.json").read_text()))
        assert sha256(path) == digest
        stress_log.record("command line, degenerate files", "clamped", f"profiles+fit on {case_id}")
    # Editing a material whose average channel has no lobe: refused in one line.
    res = run_cli("edit", tmp_path / "green_missing.binary", "--out", tmp_path / "e.binary", "--mu", "-0.5")
    assert_one_line_error(res, "green_missing", "no specular lobe")
    assert not (tmp_path / "e.binary").exists()
    stress_log.record("command line, degenerate files", "error", "edit of a file without a lobe")


# --- killed and failing writers ---------------------------------------------------------------

_SLOW_WRITER = textwrap.dedent("""
    import os, sys, time
    sys.path.insert(0, sys.argv[1])
    import numpy as np
    import addon.core.file.merl as merl

    class Slow:
        # The real file, but the data write stops halfway and waits to be killed.
        def __init__(self, fh):
            self.fh, self.writes = fh, 0
        def __enter__(self):
            return self
        def __exit__(self, *exc):
            return self.fh.__exit__(*exc)
        def write(self, data):
            self.writes += 1
            if self.writes == 2:
                view = memoryview(data)
                self.fh.write(view[: len(view) // 2])
                self.fh.flush()
                print("halfway", flush=True)
                time.sleep(600)
            return self.fh.write(data)
        def __getattr__(self, name):
            return getattr(self.fh, name)

    merl.open = lambda *a, **k: Slow(open(*a, **k))
    table = merl.MerlTable(np.full((3, merl.N_CELLS), 0.25), np.ones((3, merl.N_CELLS), bool))
    merl.write_merl(table, sys.argv[2])
""")


@pytest.mark.parametrize("existing", [False, True], ids=["new file", "replacing a file"])
def test_writer_killed_midway_never_leaves_a_half_written_destination(tmp_path, stress_log, existing):
    out = tmp_path / "edited.binary"
    if existing:
        write_merl(_const_table(0.5), out)
        before = sha256(out)
    child = subprocess.Popen(
        [sys.executable, "-c", _SLOW_WRITER, ROOT, str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout.readline().strip() == "halfway"
        temps = [p for p in os.listdir(tmp_path) if p.startswith(".tmp-brdfm-")]
        assert len(temps) == 1 and temps[0].endswith(".binary")
        assert 12 < os.path.getsize(tmp_path / temps[0]) < FILE_BYTES
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
        child.stdout.close()
        child.stderr.close()
    # The destination is what it was: absent, or the old complete file.
    if existing:
        assert sha256(out) == before
    else:
        assert not out.exists()
    # A SIGKILLed process cannot clean up: its hidden temp file is still there, and a half
    # file is refused if anyone opens it by hand...
    (stale,) = [p for p in os.listdir(tmp_path) if p.startswith(".tmp-brdfm-")]
    with pytest.raises(MerlError, match="truncated"):
        read_merl(tmp_path / stale)
    # ...and the next write removes it: the journal recorded that very file for a writer that
    # is gone (core/file/atomic.py), so it is provably the product's.
    write_merl(_const_table(0.75), tmp_path / "next.binary")
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".tmp-")]
    assert read_merl(tmp_path / "next.binary").rho[0, 0] == pytest.approx(0.75)
    stress_log.record("killed writer", "valid", "replace" if existing else "new file")


def _const_table(value):
    from addon.core.file.merl import MerlTable

    return MerlTable(np.full((3, N_CELLS), value), np.ones((3, N_CELLS), bool))


def test_cli_edit_killed_at_random_moments_leaves_old_or_complete_output(tmp_path, stress_log):
    import samples

    src = samples.sample_path("gold")
    digest = sha256(src)
    out = tmp_path / "gold_dim.binary"
    env = dict(os.environ)
    rng = np.random.default_rng(11)
    for delay in sorted(rng.uniform(0.3, 3.0, 3)):
        child = subprocess.Popen(
            [sys.executable, "-m", "addon", "edit", src, "--out", str(out), "--alpha-scale", "0.5"],
            cwd=ROOT,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(delay)
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
        if out.exists():  # whatever the moment, the file is complete or absent
            read_merl(out)
        stress_log.record("killed writer", "valid", f"CLI edit killed after {delay:.2f} s")
    res = run_cli("edit", src, "--out", out, "--alpha-scale", "0.5")
    assert res.returncode == 0, res.stderr
    table = read_merl(out)
    assert np.isfinite(table.rho).all()
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".tmp-")]
    assert sha256(src) == digest


def test_a_failing_write_removes_its_temp_and_keeps_the_old_file(tmp_path, monkeypatch, stress_log):
    import errno

    import addon.core.file.merl as merl

    out = tmp_path / "kept.binary"
    write_merl(_const_table(0.5), out)
    before = sha256(out)

    class Full:
        def __init__(self, fh):
            self.fh = fh

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return self.fh.__exit__(*exc)

        def write(self, data):
            if len(data) > 12:
                self.fh.write(memoryview(data)[:1000])
                raise OSError(errno.ENOSPC, "No space left on device")
            return self.fh.write(data)

    real_open = open
    monkeypatch.setattr(merl, "open", lambda *a, **k: Full(real_open(*a, **k)), raising=False)
    with pytest.raises(OSError, match="No space"):
        write_merl(_const_table(0.9), out)
    assert sha256(out) == before
    assert sorted(os.listdir(tmp_path)) == ["kept.binary"]
    stress_log.record("failing writer", "error", "disk full halfway")
