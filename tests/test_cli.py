"""The headless command line (SPEC §5): exit codes, one-line errors, exact JSON keys."""

import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KEYS = ["alpha", "mu_theta", "mu_phi", "sigma_tt", "sigma_tp", "sigma_pp", "skew_30", "skew_21", "skew_12",
        "skew_03", "kurt_40", "kurt_31", "kurt_22", "kurt_13", "kurt_04"]


def run(*args):
    return subprocess.run([sys.executable, "-m", "addon", *args], cwd=ROOT, capture_output=True, text=True,
                          env=dict(os.environ))


def test_help_works():
    res = run("--help")
    assert res.returncode == 0
    assert "profiles" in res.stdout and "bench" in res.stdout


def test_profiles_writes_exactly_the_spec_keys(tmp_path):
    import samples

    out = tmp_path / "p.json"
    plot = tmp_path / "p.png"
    res = run("profiles", samples.sample_path("gold"), "--out", str(out), "--elevations", "10",
              "--max-elevation", "80", "--plot", str(plot))
    assert res.returncode == 0, res.stderr
    data = json.loads(out.read_text())
    assert set(data) == {"theta_o", "kd", "r", "g", "b", "avg"}
    assert len(data["theta_o"]) == 10 and data["theta_o"][-1] == pytest.approx(1.3962634015954636)
    assert len(data["kd"]) == 3
    for ch in ("r", "g", "b", "avg"):
        assert list(data[ch]) == KEYS
        assert all(len(v) == 10 for v in data[ch].values())
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


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
    assert res.returncode == 2 and "[0, 90)" in res.stderr


def test_edit_without_sliders_copies_values_and_never_overwrites(tmp_path):
    import hashlib

    import numpy as np
    import samples
    from addon.core.merl import read_merl

    src = samples.sample_path("gold")
    digest = hashlib.sha256(open(src, "rb").read()).hexdigest()
    out = tmp_path / "same.binary"
    res = run("edit", src, "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert "achieved mean slope" in res.stdout and "largest directional albedo" in res.stdout
    np.testing.assert_array_equal(read_merl(out).rho, read_merl(src).rho)
    res = run("edit", src, "--out", src, "--alpha-scale", "0.5")
    assert res.returncode == 2 and "overwrite the input" in res.stderr
    assert hashlib.sha256(open(src, "rb").read()).hexdigest() == digest
    res = run("edit", src, "--out", str(tmp_path / "x.binary"), "--alpha", "1,2")
    assert res.returncode == 2 and "three finite numbers" in res.stderr
