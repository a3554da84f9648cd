"""Neural-BRDF networks decoded to MERL tables (addon/core/file/nbrdf.py) and the measured samples."""

import os

import numpy as np
import pytest

import samples
from addon.core.file import nbrdf
from addon.core.file.merl import MerlError, cell_indices, read_merl, tabulate
from addon.core.geometry import directions_from_half_diff, half_diff_from_directions

RGL = os.path.join(samples.MEASURED_DIR, "nbrdf-rgl-isotropic.npz")
NIELSEN = os.path.join(samples.MEASURED_DIR, "nbrdf-nielsen.npz")


def _slow_brdf(net, wi, wo):
    """float64 network value for direction pairs, the 6-vector built from the directions.

    Written apart from the decoder: the half vector and the difference vector come from the
    vectors (a local frame around h), not from the cell's angles.
    """
    w = [np.asarray(a, dtype=np.float64) for a in net.arrays()]
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    hxy = np.hypot(h[:, 0], h[:, 1])
    cp = np.where(hxy > 0, h[:, 0] / np.where(hxy > 0, hxy, 1), 1.0)
    sp = np.where(hxy > 0, h[:, 1] / np.where(hxy > 0, hxy, 1), 0.0)
    # Tangent frame of h: t is h's polar direction, b its azimuthal direction.
    t = np.stack([h[:, 2] * cp, h[:, 2] * sp, -hxy], axis=-1)
    b = np.stack([-sp, cp, np.zeros_like(cp)], axis=-1)
    d = np.stack([(wi * t).sum(-1), (wi * b).sum(-1), (wi * h).sum(-1)], axis=-1)
    x = np.concatenate([np.stack([hxy, np.zeros_like(hxy), h[:, 2]], axis=-1), d], axis=-1)
    a1 = np.maximum(x @ w[0] + w[1], 0.0)
    a2 = np.maximum(a1 @ w[2] + w[3], 0.0)
    return np.maximum(np.exp(a2 @ w[4] + w[5]) - 1.0, 0.0).T


def _random_valid_cells(table, n, seed):
    rng = np.random.default_rng(seed)
    cells = np.flatnonzero(table.valid[0])
    return rng.choice(cells, n, replace=False)


def _cell_centre_pairs(cells, seed):
    # Cell centres from the index by hand, then a random rotation about the normal (the
    # network is isotropic: the cell, and the value, must not change).
    ith, rest = np.divmod(cells, 90 * 180)
    itd, ipd = np.divmod(rest, 180)
    th = ((ith + 0.5) / 90) ** 2 * (np.pi / 2)
    td = (itd + 0.5) / 90 * (np.pi / 2)
    pd = (ipd + 0.5) / 180 * np.pi
    phi_h = np.random.default_rng(seed).uniform(-np.pi, np.pi, cells.size)
    return directions_from_half_diff(th, td, pd, phi_h)


@pytest.mark.parametrize(
    "source,name",
    [
        (RGL, "spectralon"),
        (RGL, "satin_gold"),
        (RGL, "ilm_l3_37_metallic"),
        (RGL, "irid_flake_paint1"),
        (NIELSEN, "paintedmetal"),
        (NIELSEN, "greencloth"),
    ],
)
def test_decoder_matches_float64_reference(source, name):
    net = nbrdf.load_network(source, name)
    table = nbrdf.decode(net)
    cells = _random_valid_cells(table, 4000, seed=len(name))
    wi, wo = _cell_centre_pairs(cells, seed=len(name))
    # The rotated pairs fall in the cells they came from.
    np.testing.assert_array_equal(cell_indices(*half_diff_from_directions(wi, wo)), cells)
    ref = _slow_brdf(net, wi, wo)
    got = table.rho[:, cells]
    # float32 precision: the pre-activations are sums of ~21 terms of size ~1, so their float32
    # error is ~1e-6 absolute, which exp turns into a relative error of the same order.
    np.testing.assert_allclose(got, ref, rtol=2e-5, atol=1e-6)
    assert np.isfinite(table.rho).all()


def test_missing_cells_are_the_below_horizon_ones():
    table = nbrdf.decode(nbrdf.load_network(RGL, "spectralon"))
    lam = tabulate(lambda wi, wo: np.ones((3,) + wi.shape[:-1]))
    np.testing.assert_array_equal(table.valid, lam.valid)
    assert not table.rho[~table.valid].any()


def test_spectralon_is_near_lambertian_white():
    table = nbrdf.decode(nbrdf.load_network(RGL, "spectralon"))
    rho = table.rho[:, table.valid[0]]
    med = np.median(rho, axis=1)
    np.testing.assert_allclose(med, 1.0 / np.pi, atol=0.01)


def test_chunking_does_not_change_values(monkeypatch):
    net = nbrdf.load_network(NIELSEN, "bluebook")
    full = nbrdf.decode(net)
    monkeypatch.setattr(nbrdf, "CHUNK", 997)  # a prime: chunk edges fall everywhere
    small = nbrdf.decode(net)
    np.testing.assert_array_equal(small.valid, full.valid)
    # BLAS may block a short matmul differently: equal to float32 rounding, not bit for bit.
    np.testing.assert_allclose(small.rho, full.rho, rtol=1e-5, atol=1e-7)


def _save_npy_folder(folder, net, prefix):
    os.makedirs(folder, exist_ok=True)
    for key, leaf in (("W1", "fc1"), ("W2", "fc2"), ("W3", "fc3"), ("b1", "b1"), ("b2", "b2"), ("b3", "b3")):
        np.save(os.path.join(folder, f"{prefix}{leaf}.npy"), getattr(net, key))


def test_single_npz_npy_folder_and_set_agree(tmp_path):
    net = nbrdf.load_network(RGL, "paper_red")
    single = tmp_path / "paper_red.npz"
    np.savez(single, **{k: getattr(net, k) for k in nbrdf.LAYER_KEYS})
    assert nbrdf.list_materials(single) == ["paper_red"]
    _save_npy_folder(tmp_path / "npy", net, "paper_red_")
    _save_npy_folder(tmp_path / "npy", nbrdf.load_network(RGL, "cardboard"), "cardboard_")
    assert nbrdf.list_materials(tmp_path / "npy") == ["cardboard", "paper_red"]
    _save_npy_folder(tmp_path / "bare", net, "")  # the Mitsuba plugin's basename + "fc1.npy"
    ref = nbrdf.decode(net).rho
    for source, name in ((single, None), (tmp_path / "npy", "paper_red"), (tmp_path / "bare", None)):
        other = nbrdf.load_network(source, name)
        assert other.digest() == net.digest()
        np.testing.assert_array_equal(nbrdf.decode(other).rho, ref)


@pytest.mark.parametrize("layout", ["save_weights", "model", "keras3"])
def test_keras_layouts_give_the_layers_in_chain_order(layout):
    net = nbrdf.load_network(RGL, "satin_blue")
    names = {
        "save_weights": "dense_{n}/dense_{n}/{v}:0",
        "model": "model_weights/dense_{n}/dense_{n}/{v}:0",
        "keras3": "layers/dense_{n}/vars/{i}",
    }[layout]
    datasets = {}
    # Layer numbers that do not follow the order (Keras numbers them per session).
    for i, n in zip((1, 2, 3), (7, 5, 9)):
        datasets[names.format(n=n, v="kernel", i=0)] = getattr(net, f"W{i}")
        datasets[names.format(n=n, v="bias", i=1)] = getattr(net, f"b{i}")
        if layout == "model":  # Adam's slots, shaped like the weights
            for slot in ("m", "v"):
                datasets[f"optimizer_weights/Adam/dense_{n}/kernel/{slot}:0"] = getattr(net, f"W{i}") * 0
                datasets[f"optimizer_weights/Adam/{slot}/dense_{n}/bias:0"] = getattr(net, f"b{i}") * 0
    layers = nbrdf.dense_layers(datasets)
    for k in nbrdf.LAYER_KEYS:
        np.testing.assert_array_equal(layers[k], getattr(net, k))
    with pytest.raises(MerlError, match="expected 3 dense layers"):
        nbrdf.dense_layers({k: v for k, v in datasets.items() if "dense_9" not in k}, "x.h5")


def test_keras_h5(tmp_path):
    import h5py  # in requirements.txt: the Keras path is tested for real, never skipped

    net = nbrdf.load_network(RGL, "satin_blue")
    path = tmp_path / "satin_blue.h5"
    # The layout Keras' save_weights writes: a group per layer, layer names numbered freely.
    with h5py.File(path, "w") as f:
        for i, layer in zip((3, 1, 2), ("dense_9", "dense_7", "dense_8")):
            g = f.create_group(layer).create_group(layer)
            g["kernel:0"] = getattr(net, f"W{i}")
            g["bias:0"] = getattr(net, f"b{i}")
    assert nbrdf.load_network(path).digest() == net.digest()


def _bad(tmp_path, name, content=None, **arrays):
    path = tmp_path / name
    if arrays:
        np.savez(path, **arrays)
    else:
        path.write_bytes(content or b"")
    return path


def test_bad_sources_raise_one_line_errors_naming_the_file(tmp_path):
    net = nbrdf.load_network(RGL, "spectralon")
    good = {k: getattr(net, k) for k in nbrdf.LAYER_KEYS}
    nan = dict(good, W2=np.where(np.eye(21, dtype=bool), np.nan, net.W2))
    cases = [
        (_bad(tmp_path, "empty.npz"), "not a valid Neural-BRDF weights file"),
        (_bad(tmp_path, "text.npz", b"hello"), "not a valid Neural-BRDF weights file"),
        (_bad(tmp_path, "other.npz", a=np.ones(3)), "no network weights"),
        (_bad(tmp_path, "shape.npz", **dict(good, W1=np.ones((5, 21), np.float32))), "not a 6-input"),
        (_bad(tmp_path, "nan.npz", **nan), "non-finite"),
        (_bad(tmp_path, "lack.npz", **{k: v for k, v in good.items() if k != "b3"}), "lacks weight"),
        (tmp_path / "absent.npz", "no such file"),
        (tmp_path, "a folder with no network weights"),
    ]
    for path, fault in cases:
        with pytest.raises(MerlError) as err:
            nbrdf.load_network(path)
        msg = str(err.value)
        assert fault in msg and str(path) in msg and "\n" not in msg, msg
    with pytest.raises(MerlError, match="choose one"):
        nbrdf.load_network(RGL)
    with pytest.raises(MerlError, match="no material 'satin_golden'.*satin_gold"):
        nbrdf.load_network(RGL, "satin_golden")
    huge = _bad(tmp_path, "huge.npz", **dict(good, b3=np.full(3, 1e4, np.float32)))
    with pytest.raises(MerlError, match="beyond any reflectance"):
        nbrdf.decode(nbrdf.load_network(huge))


def test_parse_source(tmp_path):
    from addon.core.file import sources

    assert sources.parse_source(f"{RGL}:satin_gold") == (RGL, "satin_gold")
    assert sources.parse_source(RGL) == (RGL, None)
    odd = tmp_path / "odd.npz:x"
    odd.write_bytes(b"")
    assert sources.parse_source(str(odd)) == (str(odd), None)
    assert sources.parse_source("plain.binary") == ("plain.binary", None)


def test_measured_names():
    names = samples.measured_names()
    assert len(names) == len(set(names)) == 59
    assert sum(n.startswith("rgl/") for n in names) == 51
    assert "rgl/cardboard" in names and "nielsen/cardboard" in names


def test_measured_sample_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("BRDF_MOMENTS_SAMPLES", str(tmp_path / "cache"))
    weights = tmp_path / "set.npz"
    net = nbrdf.load_network(NIELSEN, "notebook")
    arrays = {f"notebook/{k}": getattr(net, k) for k in nbrdf.LAYER_KEYS}
    np.savez(weights, **arrays)
    monkeypatch.setattr(samples, "MEASURED_DIR", str(tmp_path))
    monkeypatch.setitem(samples.MEASURED_SETS, "test", "set.npz")
    path = samples.sample_path("test/notebook")
    table = read_merl(path)
    ref = nbrdf.decode(net)
    np.testing.assert_array_equal(table.valid, ref.valid)
    np.testing.assert_allclose(table.rho, ref.rho, rtol=1e-15)
    mtime = os.stat(path).st_mtime_ns
    assert samples.sample_path("test/notebook") == path and os.stat(path).st_mtime_ns == mtime
    # Changed weights: a new table, and the stale one is gone.
    arrays["notebook/b3"] = arrays["notebook/b3"] + np.float32(0.1)
    np.savez(weights, **arrays)
    new = samples.sample_path("test/notebook")
    assert new != path and not os.path.exists(path)
    assert read_merl(new).rho[0].max() > table.rho[0].max()
    assert os.path.basename(new) == "test-notebook.binary" and read_merl(new).name == "test-notebook"
    assert os.listdir(tmp_path / "cache" / "measured") == [os.path.basename(os.path.dirname(new))]
    with pytest.raises(KeyError, match="rgl/NAME"):
        samples.sample_path("nope/thing")
    with pytest.raises(KeyError, match="no material"):
        samples.sample_path("test/absent")


def test_h5_without_h5py_is_a_one_line_error(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "h5py", None)  # import h5py now raises ImportError
    path = tmp_path / "model.h5"
    path.write_bytes(b"\x89HDF\r\n\x1a\n")
    with pytest.raises(MerlError, match=r"model.h5: reading Keras .h5 files needs the h5py package"):
        nbrdf.load_network(path)
