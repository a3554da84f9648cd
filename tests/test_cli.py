"""The headless command line (SPEC §5): exit codes, one-line errors, exact JSON keys."""

import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KEYS = [
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
]


def run(*args):
    return subprocess.run(
        [sys.executable, "-m", "addon", *args], cwd=ROOT, capture_output=True, text=True, env=dict(os.environ)
    )


def test_help_works():
    res = run("--help")
    assert res.returncode == 0
    assert "profiles" in res.stdout and "bench" in res.stdout


@pytest.mark.slow
def test_profiles_writes_exactly_the_spec_keys(tmp_path):
    import samples

    out = tmp_path / "p.json"
    plot = tmp_path / "p.png"
    res = run(
        "profiles",
        samples.sample_path("gold"),
        "--out",
        str(out),
        "--elevations",
        "10",
        "--max-elevation",
        "80",
        "--plot",
        str(plot),
    )
    assert res.returncode == 0, res.stderr
    data = json.loads(out.read_text())
    assert set(data) == {"theta_o", "kd", "r", "g", "b", "avg"}
    assert len(data["theta_o"]) == 10 and data["theta_o"][-1] == pytest.approx(1.3962634015954636)
    assert len(data["kd"]) == 3
    for ch in ("r", "g", "b", "avg"):
        assert list(data[ch]) == KEYS
        assert all(len(v) == 10 for v in data[ch].values())
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_max_order_limits_the_keys(tmp_path):
    import samples

    out = tmp_path / "p.json"
    res = run("profiles", samples.sample_path("gold"), "--out", str(out), "--elevations", "3", "--max-order", "1")
    assert res.returncode == 0, res.stderr
    assert list(json.loads(out.read_text())["avg"]) == KEYS[:3]


@pytest.mark.parametrize("content, fault", [(b"\x00" * 100, "wrong header"), (b"", "too short")])
def test_bad_input_exits_2_with_one_line(tmp_path, content, fault):
    bad = tmp_path / "broken.binary"
    bad.write_bytes(content)
    out = tmp_path / "o.json"
    res = run("profiles", str(bad), "--out", str(out))
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and str(bad) in lines[0] and fault in lines[0]
    assert "Traceback" not in res.stderr
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.binary"]


def test_missing_file_and_bad_options_exit_2(tmp_path):
    res = run("profiles", str(tmp_path / "none.binary"), "--out", str(tmp_path / "o.json"))
    assert res.returncode == 2 and "none.binary" in res.stderr and "Traceback" not in res.stderr
    res = run("profiles", str(tmp_path / "none.binary"), "--out", "x.json", "--max-elevation", "95")
    assert res.returncode == 2 and "--max-elevation: must be at most 89.99" in res.stderr


@pytest.mark.slow
def test_edit_without_sliders_copies_values_and_never_overwrites(tmp_path):
    import hashlib

    import numpy as np

    import samples
    from addon.core.file.merl import read_merl

    src = samples.sample_path("gold")
    digest = hashlib.sha256(open(src, "rb").read()).hexdigest()
    out = tmp_path / "same.binary"
    res = run("edit", src, "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert "re-fit    mean slope" in res.stdout and "largest directional albedo" in res.stdout
    assert "announced mean slope" in res.stdout
    np.testing.assert_array_equal(read_merl(out).rho, read_merl(src).rho)
    res = run("edit", src, "--out", src, "--alpha-scale", "0.5")
    assert res.returncode == 2 and "overwrite the input" in res.stderr
    assert hashlib.sha256(open(src, "rb").read()).hexdigest() == digest
    res = run("edit", src, "--out", str(tmp_path / "x.binary"), "--alpha", "1,2")
    assert res.returncode == 2 and "three finite numbers" in res.stderr


def test_fit_command_writes_the_spec_shape(tmp_path):
    import samples

    out = tmp_path / "fits.json"
    res = run("fit", samples.sample_path("gold"), samples.sample_path("ggx_rough"), "--out", str(out))
    assert res.returncode == 0, res.stderr
    data = json.loads(out.read_text())
    assert set(data) == {"materials", "joint", "correlation"}
    for name in ("gold", "ggx_rough"):
        f = data["materials"][name]
        for k in ("alpha_b", "theta0", "theta1", "alpha1", "m1", "mu_slope", "sigma2"):
            assert isinstance(f[k], float)
        for k in ("energy", "mean", "variance"):
            assert set(f[k]) == {"mae", "rmse"}
        assert 0 <= f["theta0"] < f["theta1"] <= 1.5707963267948966
    assert {"theta0", "theta1"} <= set(data["joint"]) and {"a", "b", "c"} <= set(data["correlation"])


def test_fit_and_analyze_report_bad_files_with_exit_2(tmp_path):
    import shutil

    import samples

    bad = tmp_path / "set" / "broken.binary"
    bad.parent.mkdir()
    bad.write_bytes(b"not a brdf at all")
    res = run("fit", str(bad), "--out", str(tmp_path / "f.json"))
    assert res.returncode == 2 and "broken.binary" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "f.json").exists()
    shutil.copy(samples.sample_path("gold"), tmp_path / "set" / "gold.binary")
    out = tmp_path / "results"
    res = run("analyze", str(tmp_path / "set"), "--out", str(out), "--no-plots")
    assert res.returncode == 2
    assert "broken.binary" in res.stderr and "wrong header" in res.stderr and "Traceback" not in res.stderr
    assert (out / "materials" / "gold.json").exists() and (out / "summary.csv").exists()
    assert "gold" in (out / "summary.csv").read_text()
    empty = tmp_path / "empty"
    empty.mkdir()
    res = run("analyze", str(empty), "--out", str(tmp_path / "r2"))
    assert res.returncode == 2 and "no .binary files" in res.stderr


def test_every_help_prints_and_render_says_its_default():
    for cmd in ([], ["profiles"], ["fit"], ["analyze"], ["edit"], ["render"], ["bench"]):
        res = run(*cmd, "--help")
        assert res.returncode == 0 and "usage:" in res.stdout and not res.stderr, (cmd, res.stderr)
    text = " ".join(run("render", "--help").stdout.split())
    from addon.core.preview.live import FINAL_SAMPLES
    from addon.tools.cli import RENDER_BAKE_SAMPLES, RENDER_DEFAULT_ERROR, build_parser

    # the default is the accurate baked path, at the panel's bake, and the help says its error
    args = build_parser().parse_args(["render", "x.binary", "--out", "o.png"])
    assert args.path == "baked" and args.bake_samples == RENDER_BAKE_SAMPLES == FINAL_SAMPLES
    assert "baked (default" in text and " ".join(RENDER_DEFAULT_ERROR.split()) in text


def test_edit_takes_relative_moves_and_reports_the_operator(tmp_path):
    """--sigma2 x0.5 halves the fitted variance (the written file re-fits to it within 1 %),
    the output names the roughness scale, floor and masking, and malformed moves exit 2."""
    import samples
    from addon.core.file.merl import read_merl
    from addon.core.fits.curves import fit_material
    from addon.core.profiles.compute import compute_profiles

    src = samples.sample_path("ggx_glossy")
    fitted = fit_material(compute_profiles(read_merl(src)))["sigma2"]
    out = tmp_path / "half.binary"
    report = tmp_path / "half.json"
    plot = tmp_path / "half.png"
    res = run("edit", src, "--out", str(out), "--sigma2", "x0.5", "--report", str(report), "--plot", str(plot))
    assert res.returncode == 0, res.stderr
    assert plot.stat().st_size > 10_000 and plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "operator  roughness x" in res.stdout and "masking separable" in res.stdout
    assert "re-read   mean slope" in res.stdout
    got = fit_material(compute_profiles(read_merl(out)))["sigma2"]
    assert got == pytest.approx(0.5 * fitted, rel=0.01)
    rep = json.loads(report.read_text())
    # the announcement is the table's own measurement: no judged view is out of its reach
    assert any(rep["judged"]) and not any(rep["out_of_reach"])
    op = rep["operator"]
    assert 0.5 < op["roughness_scale"] < 0.7 and op["masking"] == "separable" and not op["clamped"]
    for bad, says in (("x0", "above 0"), ("xabc", "not a number"), ("x-1", "above 0")):
        res = run("edit", src, "--out", str(tmp_path / "bad.binary"), "--sigma2", bad)
        assert res.returncode == 2 and says in res.stderr and "Traceback" not in res.stderr
    res = run("edit", src, "--out", str(tmp_path / "bad.binary"), "--mu", "+abc")
    assert res.returncode == 2 and "not a number" in res.stderr
    res = run("edit", src, "--out", str(tmp_path / "bad.binary"), "--mu-by", "5")
    assert res.returncode == 2 and "must be within" in res.stderr
    assert not (tmp_path / "bad.binary").exists()
    res = run("edit", src, "--out", str(tmp_path / "p.binary"), "--sigma2", "x0.5", "--plot", src)
    assert res.returncode != 0 and read_merl(src).rho.size  # the plot may not overwrite the input
