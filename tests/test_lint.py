"""The code base passes ``ruff check`` with the rules in pyproject.toml (the test command runs it)."""

import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _ruff():
    beside = os.path.join(os.path.dirname(sys.executable), "ruff")  # the venv's, pinned in requirements.txt
    return beside if os.path.isfile(beside) else shutil.which("ruff")


def test_ruff_check_finds_nothing():
    ruff = _ruff()
    if ruff is None:
        if os.environ.get("BRDF_MOMENTS_REQUIRE_LANES"):
            pytest.fail("ruff is not installed (scripts/setup.sh installs it from requirements.txt)")
        pytest.skip("no ruff (scripts/setup.sh installs it from requirements.txt)")
    res = subprocess.run(
        [ruff, "check", "--no-cache", "--output-format", "concise", "."],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, (res.stdout + res.stderr)[-6000:]


def test_ruff_format_changes_nothing():
    """The code is kept as ``ruff format`` writes it (settings in pyproject.toml)."""
    ruff = _ruff()
    if ruff is None:
        if os.environ.get("BRDF_MOMENTS_REQUIRE_LANES"):
            pytest.fail("ruff is not installed (scripts/setup.sh installs it from requirements.txt)")
        pytest.skip("no ruff (scripts/setup.sh installs it from requirements.txt)")
    res = subprocess.run(
        [ruff, "format", "--check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0, (res.stdout + res.stderr)[-6000:]
