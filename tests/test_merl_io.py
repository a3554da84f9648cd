"""MERL reading, writing and lookup (SPEC §2)."""

import math
import os
import struct

import numpy as np
import pytest

from addon.core.file.merl import (
    CHANNEL_SCALES,
    FILE_BYTES,
    N_CELLS,
    MerlError,
    MerlTable,
    cell_indices,
    lookup,
    lookup_angles,
    read_merl,
    tabulate,
    write_merl,
)
from addon.core.geometry import directions_from_half_diff, view_centred


def _write_raw(path, dims=(90, 90, 180), values=None, extra=b""):
    if values is None:
        values = np.full(3 * N_CELLS, 1500.0)
    with open(path, "wb") as fh:
        fh.write(struct.pack("<3i", *dims))
        fh.write(np.asarray(values, dtype="<f8").tobytes())
        fh.write(extra)
    return str(path)


def _random_table(seed=0, missing=0.03):
    rng = np.random.default_rng(seed)
    rho = rng.uniform(0.0, 2.0, (3, N_CELLS))
    valid = rng.uniform(size=(3, N_CELLS)) > missing
    return MerlTable(np.where(valid, rho, 0.0), valid)


def test_round_trip_is_bit_exact(tmp_path):
    table = _random_table()
    path = tmp_path / "t.binary"
    write_merl(table, path)
    assert os.path.getsize(path) == FILE_BYTES
    back = read_merl(path)
    np.testing.assert_array_equal(back.valid, table.valid)
    # The scale is applied on read and removed on write; allow the float rounding of one
    # multiply and one divide.
    np.testing.assert_allclose(back.rho, table.rho, rtol=4e-16, atol=0)
    again = tmp_path / "u.binary"
    write_merl(back, again)
    assert again.read_bytes() == path.read_bytes()


def test_read_applies_channel_scales_and_masks_negatives(tmp_path):
    stored = np.empty((3, N_CELLS))
    stored[0], stored[1], stored[2] = 1500.0, 1500.0 / 1.15, 1500.0 / 1.66
    stored[:, 7] = -1.0
    table = read_merl(_write_raw(tmp_path / "s.binary", values=stored.ravel()))
    np.testing.assert_allclose(table.rho[:, 0], [1.0, 1.0, 1.0], rtol=1e-15)
    assert not table.valid[:, 7].any()
    assert (table.rho[:, 7] == 0.0).all()  # missing is masked, never a negative value
    assert table.valid.sum() == 3 * (N_CELLS - 1)
    np.testing.assert_allclose(CHANNEL_SCALES, [1 / 1500, 1.15 / 1500, 1.66 / 1500])


@pytest.mark.parametrize(
    "case, fault",
    [
        ("truncated", "truncated"),
        ("oversized", "oversized"),
        ("header", "wrong header"),
        ("tiny", "too short"),
        ("nan", "NaN"),
        ("inf", "inf"),
    ],
)
def test_bad_files_are_refused_naming_file_and_fault(tmp_path, case, fault):
    path = tmp_path / f"bad-{case}.binary"
    values = np.full(3 * N_CELLS, 10.0)
    if case == "truncated":
        _write_raw(path)
        with open(path, "r+b") as fh:
            fh.truncate(FILE_BYTES - 8)
    elif case == "oversized":
        _write_raw(path, extra=b"\0" * 8)
    elif case == "header":
        _write_raw(path, dims=(90, 90, 360))
    elif case == "tiny":
        path.write_bytes(b"\1\2\3")
    elif case == "nan":
        values[12345] = np.nan
        _write_raw(path, values=values)
    elif case == "inf":
        values[N_CELLS + 3] = -np.inf
        _write_raw(path, values=values)
    with pytest.raises(MerlError) as info:
        read_merl(path)
    msg = str(info.value)
    assert str(path) in msg and fault in msg


def test_missing_file_is_a_merl_error(tmp_path):
    with pytest.raises(MerlError, match="cannot read"):
        read_merl(tmp_path / "nope.binary")


def test_write_is_atomic_and_never_overwrites_input(tmp_path):
    table = _random_table(1)
    src = tmp_path / "in.binary"
    write_merl(table, src)
    before = src.read_bytes()
    loaded = read_merl(src)
    with pytest.raises(MerlError, match="overwrite the input"):
        write_merl(loaded, src)
    with pytest.raises(MerlError, match="overwrite the input"):
        write_merl(table, src, source=src)
    assert src.read_bytes() == before
    # A failure mid-write (non-finite data is refused before any byte is written; an
    # interrupted write leaves only the temp file, which is removed).
    bad = MerlTable(np.full((3, N_CELLS), np.inf), np.ones((3, N_CELLS), bool))
    with pytest.raises(MerlError):
        write_merl(bad, tmp_path / "out.binary")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.binary"]


def test_interrupted_write_leaves_nothing(tmp_path, monkeypatch):
    table = _random_table(2)
    import addon.core.file.merl as merl

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(merl.os, "replace", boom)
    with pytest.raises(KeyboardInterrupt):
        write_merl(table, tmp_path / "x.binary")
    assert list(tmp_path.iterdir()) == []


def _reference_index(theta_h, theta_d, phi_d):
    """MERL's reference reader, transcribed from its published description, one scalar at a time."""
    if theta_h <= 0.0:
        ith = 0
    else:
        ith = min(max(int(math.sqrt(theta_h / (math.pi / 2)) * 90), 0), 89)
    itd = min(max(int(theta_d / (math.pi / 2) * 90), 0), 89)
    if phi_d < 0.0:
        phi_d += math.pi
    ipd = min(max(int(phi_d / math.pi * 180), 0), 179)
    return ipd + 180 * (itd + 90 * ith)


def test_nearest_index_matches_scalar_reader():
    rng = np.random.default_rng(3)
    th = rng.uniform(-0.01, math.pi / 2, 2000)
    td = rng.uniform(0, math.pi / 2, 2000)
    pd = rng.uniform(-math.pi, math.pi, 2000)
    got = cell_indices(th, td, pd)
    want = [_reference_index(a, b, c) for a, b, c in zip(th, td, pd)]
    np.testing.assert_array_equal(got, want)


def test_lookup_of_tabulated_function_at_cell_centres_is_exact():
    def brdf(wi, wo):
        # A reciprocal, smooth function of the cell angles.
        c = np.sum(wi * wo, axis=-1)
        return np.stack([1 + c, 2 + c * c, 3 - c])

    table = tabulate(brdf)
    from addon.core.file.merl import cell_centres

    th, td, pd = cell_centres()
    pick = np.random.default_rng(4).integers(0, N_CELLS, 500)
    wi, wo = directions_from_half_diff(th[pick], td[pick], pd[pick])
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    vals, valid = lookup(table, wi[ok], wo[ok])
    assert valid.all()
    np.testing.assert_allclose(vals, brdf(wi[ok], wo[ok]), rtol=1e-12)
    # Trilinear at a cell centre is the cell value (all neighbours measured).
    tv, tvalid = lookup_angles(table, th[pick][ok], td[pick][ok], pd[pick][ok], "trilinear")
    inner = tvalid.all(axis=0)
    np.testing.assert_allclose(tv[:, inner], vals[:, inner], rtol=1e-12)


def test_lookup_is_reciprocal_and_bilateral():
    table = _random_table(5, missing=0.0)
    rng = np.random.default_rng(6)
    wi = view_centred(rng.uniform(-1.4, 1.4, 300), rng.uniform(-1.4, 1.4, 300))
    wo = view_centred(rng.uniform(-1.4, 1.4, 300), rng.uniform(-1.4, 1.4, 300))
    a, _ = lookup(table, wi, wo)
    b, _ = lookup(table, wo, wi)
    # Swapping adds pi to phi_d, which folds back onto the same cell.
    np.testing.assert_array_equal(a, b)


def test_trilinear_ignores_missing_neighbours_and_wraps_phi_d():
    valid = np.ones((3, N_CELLS), bool)
    rho = np.ones((3, N_CELLS))
    # Make one cell missing with a huge stored value: it must not leak in.
    k = 3 + 180 * (40 + 90 * 40)
    rho[:, k] = 1e9
    valid[:, k] = False
    table = MerlTable(np.where(valid, rho, 0.0), valid)
    from addon.core.file.merl import cell_centres

    th, td, pd = cell_centres()
    pts = [k, k + 1]
    v, ok = lookup_angles(table, th[pts] * 1.001, td[pts] + 0.003, pd[pts] + 0.004, "trilinear")
    assert ok.all()
    np.testing.assert_allclose(v, 1.0, rtol=1e-12)
    # phi_d just below pi and just above 0 are neighbours through the fold.
    ramp = np.tile(np.cos(2 * (np.arange(180) + 0.5) * np.pi / 180), 90 * 90)
    t2 = MerlTable(np.stack([ramp] * 3), np.ones((3, N_CELLS), bool))
    lo, _ = lookup_angles(t2, np.array([0.3]), np.array([0.4]), np.array([1e-6]), "trilinear")
    hi, _ = lookup_angles(t2, np.array([0.3]), np.array([0.4]), np.array([math.pi - 1e-6]), "trilinear")
    np.testing.assert_allclose(lo, hi, rtol=1e-4)
    np.testing.assert_allclose(lo, np.cos(2 * 0.5 * np.pi / 180) * 1.0, rtol=2e-3)


def test_direct_view_cell_formula_matches_the_general_conversion():
    from addon.core.file.merl import cell_indices_view
    from addon.core.geometry import half_diff_from_directions

    rng = np.random.default_rng(9)
    t = rng.uniform(-1.57, 1.57, 20000)
    p = rng.uniform(-1.57, 1.57, 20000)
    e = rng.uniform(0.0, 1.57, 20000)
    wi = view_centred(t, p)
    wo = np.stack([np.sin(e), 0 * e, np.cos(e)], axis=-1)
    want = cell_indices(*half_diff_from_directions(wi, wo))
    got = cell_indices_view(t, p, np.sin(e), np.cos(e))
    # Rounding can put a point exactly on a cell edge on either side; allow a handful.
    assert np.mean(got != want) < 1e-3
    # float32 (the synthesis's precision) moves a lookup only at cell edges too.
    f32 = cell_indices_view(t.astype(np.float32), p.astype(np.float32), np.sin(e), np.cos(e))
    assert f32.dtype.kind == "i" and np.mean(f32 != want) < 1e-3


def test_direct_view_cell_formula_takes_scalars_and_broadcasts():
    from addon.core.file.merl import cell_indices_view

    t = np.linspace(-1.5, 1.5, 7)[:, None]
    p = np.linspace(-1.5, 1.5, 5)[None, :]
    e = np.array([0.0, 0.4, 1.2])[:, None, None]
    grid = cell_indices_view(t, p, np.sin(e), np.cos(e))
    assert grid.shape == (3, 7, 5)
    for k in range(3):
        for i in range(7):
            for j in range(5):
                one = cell_indices_view(float(t[i, 0]), float(p[0, j]), math.sin(e[k, 0, 0]), math.cos(e[k, 0, 0]))
                assert np.shape(one) == () and int(one) == grid[k, i, j]
