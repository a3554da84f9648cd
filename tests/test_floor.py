"""The diffuse floor: the paper's minimum over the 45° slice, and the robust option."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

import samples
from addon.core.file import nbrdf
from addon.core.file.merl import MerlTable, tabulate
from addon.core.profiles.compute import DIFFUSE_VIEW, ROBUST_MAX_ANGLE, compute_profiles, diffuse_floor
from addon.core.profiles.integrate import get_operator

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RGL = os.path.join(samples.MEASURED_DIR, "nbrdf-rgl-isotropic.npz")


@pytest.fixture(scope="module")
def slice_cells():
    """The 45° slice's cells, split by whether both directions are within 70° of the normal,
    worked out here from the directions of the cell centres (not the floor's formula)."""
    from addon.core.geometry import directions_from_half_diff

    cells = np.asarray(get_operator(np.array([DIFFUSE_VIEW]), memo=False).view(0)[0])
    ith, rest = np.divmod(cells, 90 * 180)
    itd, ipd = np.divmod(rest, 180)
    wi, wo = directions_from_half_diff(
        ((ith + 0.5) / 90) ** 2 * math.pi / 2, (itd + 0.5) / 90 * math.pi / 2, (ipd + 0.5) / 180 * math.pi
    )
    lowest = np.minimum(wi[:, 2], wo[:, 2])
    inner = lowest >= math.cos(ROBUST_MAX_ANGLE) + 1e-9
    grazing = lowest < math.cos(math.radians(80.0))
    return cells, inner, grazing


def _constant(value=0.3):
    lam = tabulate(lambda wi, wo: np.full((3,) + wi.shape[:-1], value))
    return MerlTable(lam.rho.copy(), lam.valid.copy())


def test_one_low_cell_or_a_dark_grazing_band_sets_the_minimum_not_the_robust_floor(slice_cells):
    cells, inner, grazing = slice_cells
    t = _constant(0.3)
    t.rho[:, cells[inner][len(cells[inner]) // 2]] = 0.001  # one low cell in the well-measured part
    t.rho[:, cells[grazing & t.valid[0, cells]]] = 0.0  # and every grazing cell dark
    np.testing.assert_allclose(diffuse_floor(t), 0.0)
    np.testing.assert_allclose(diffuse_floor(t, method="robust"), 0.3)


def test_the_robust_floor_is_a_low_percentile_of_the_inner_cells(slice_cells):
    cells, inner, _ = slice_cells
    rng = np.random.default_rng(3)
    inner_cells = cells[inner]
    t = _constant(0.3)
    # A fifth of the inner cells lower: far more than 5 % of the area, so the floor follows them.
    low = rng.choice(inner_cells, len(inner_cells) // 5, replace=False)
    t.rho[:, low] = 0.1
    np.testing.assert_allclose(diffuse_floor(t, method="robust"), 0.1)
    # One in a thousand lower: the floor stays.
    t = _constant(0.3)
    t.rho[:, rng.choice(inner_cells, len(inner_cells) // 1000, replace=False)] = 0.1
    np.testing.assert_allclose(diffuse_floor(t, method="robust"), 0.3)


def test_spectralon_minimum_and_robust_floor():
    # Measured: a near-Lambertian white whose minimum over the 45° slice is a grazing cell near 0.
    table = nbrdf.decode(nbrdf.load_network(RGL, "spectralon"))
    assert diffuse_floor(table).max() < 0.01
    robust = diffuse_floor(table, method="robust")
    assert np.all((robust > 0.25) & (robust < 1 / math.pi))


def test_unknown_floor_is_refused():
    with pytest.raises(ValueError, match="unknown diffuse floor"):
        compute_profiles(_constant(), np.radians([10.0]), floor="median")


def test_cli_floor_option(tmp_path):
    def run(*args):
        return subprocess.run(
            [sys.executable, "-m", "addon", *args],
            cwd=ROOT,
            capture_output=True,
            text=True,
            env=dict(os.environ),
            timeout=600,
        )

    kd = {}
    for floor in ("min", "robust"):
        out = tmp_path / f"{floor}.json"
        res = run("profiles", f"{RGL}:paper_white", "--out", str(out), "--floor", floor)
        assert res.returncode == 0, res.stderr
        kd[floor] = json.loads(out.read_text())["kd"]
    table = nbrdf.read_table(f"{RGL}:paper_white")
    np.testing.assert_allclose(kd["min"], diffuse_floor(table), rtol=1e-12)
    np.testing.assert_allclose(kd["robust"], diffuse_floor(table, method="robust"), rtol=1e-12)
    res = run("fit", f"{RGL}:paper_white", "--out", str(tmp_path / "f.json"), "--floor", "middle")
    assert res.returncode == 2 and "--floor" in res.stderr
