"""Neural-BRDF networks (Sztrajman et al. 2021) decoded into MERL tables; numpy only.

A network is a 6 -> 21 -> 21 -> 3 perceptron: ``x1 = relu(x W1 + b1)``,
``x2 = relu(x1 W2 + b2)``, ``y = x2 W3 + b3``, BRDF ``= max(exp(y) - 1, 0)`` per RGB channel,
in 1/sr. The input row is the half vector ``(sin th, 0, cos th)`` (phi_h = 0, isotropic)
followed by the difference vector ``(sin td cos pd, sin td sin pd, cos td)``.

Weights are read from
- an ``.npz`` with the keys ``W1 b1 W2 b2 W3 b3`` (one material) or ``NAME/W1`` ... (a set);
- a folder of ``.npy`` files as the Neural-BRDF project's ``h5_to_npy.py`` writes them,
  ``NAME_fc1.npy NAME_fc2.npy NAME_fc3.npy NAME_b1.npy NAME_b2.npy NAME_b3.npy`` (its Mitsuba
  plugin reads ``basename + "fc1.npy"``, so a bare ``fc1.npy`` ... folder is one material);
- a Keras ``.h5`` (weights-only or a whole model) when ``h5py`` can be imported.

Sample position: each MERL cell is evaluated at its centre, the same positions at which
``merl.tabulate`` samples analytic BRDFs (``merl.cell_centres``), so a decoded table and a
tabulated one are comparable cell for cell. Cells with either direction at or below the
horizon are marked missing, as ``tabulate`` does.

Every fault is a ``MerlError`` naming the file, so callers print the same one-line errors
as for bad MERL files.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

import numpy as np

from ..geometry import HALF_PI
from .merl import MAX_REFLECTANCE, N_CELLS, RES_PD, RES_TD, RES_TH, MerlError, MerlTable
from .sources import is_weights_source, parse_source

# Bump when the decoded values change (position, clipping): cached tables then re-decode.
DECODER_VERSION = 1
# Rows per matmul chunk: 2^16 rows x 21 float32 is ~5 MB per layer, whatever the table size.
CHUNK = 1 << 16
LAYER_KEYS = ("W1", "b1", "W2", "b2", "W3", "b3")
_NPY_KEYS = {"W1": "fc1", "b1": "b1", "W2": "fc2", "b2": "b2", "W3": "fc3", "b3": "b3"}


class WeightsError(MerlError):
    """A Neural-BRDF weights source that cannot be used (file and fault in the message)."""


def _names(names) -> str:
    from .safeio import display_path

    return ", ".join(display_path(n) for n in names)  # control characters escaped: one line


def _why(exc) -> str:
    """An exception as a short one-line reason (library messages may span lines)."""
    text = " ".join(str(exc).split()) or exc.__class__.__name__
    return text[:200]


@dataclass
class Network:
    name: str
    W1: np.ndarray
    b1: np.ndarray
    W2: np.ndarray
    b2: np.ndarray
    W3: np.ndarray
    b3: np.ndarray
    source: str | None = None

    def arrays(self):
        return [getattr(self, k) for k in LAYER_KEYS]

    def digest(self) -> str:
        """A hash of the weights (and the decoder version): the cache key of a decoded table."""
        h = hashlib.sha256(f"nbrdf-v{DECODER_VERSION}".encode())
        for a in self.arrays():
            h.update(str(a.shape).encode())
            h.update(np.ascontiguousarray(a, dtype="<f4").tobytes())
        return h.hexdigest()[:16]


def _network(path, name, arrays: dict) -> Network:
    """Validate shapes and values of one material's weights."""
    missing = [k for k in LAYER_KEYS if k not in arrays]
    if missing:
        raise WeightsError(path, f"material {name!r} lacks weight(s) {', '.join(missing)}")
    try:
        a = {k: np.asarray(arrays[k]) for k in LAYER_KEYS}
    except Exception as exc:  # an unreadable array inside the container
        raise WeightsError(path, f"material {name!r}: unreadable weights ({_why(exc)})") from None
    for k, v in a.items():
        if v.dtype.kind not in "fiu":
            raise WeightsError(path, f"material {name!r}: {k} is not numeric ({v.dtype})")
    w1, b1, w2, b2, w3, b3 = (a[k] for k in LAYER_KEYS)
    shapes_ok = (
        w1.ndim == 2
        and w1.shape[0] == 6
        and b1.shape == (w1.shape[1],)
        and w2.ndim == 2
        and w2.shape[0] == w1.shape[1]
        and b2.shape == (w2.shape[1],)
        and w3.ndim == 2
        and w3.shape == (w2.shape[1], 3)
        and b3.shape == (3,)
    )
    if not shapes_ok:
        got = ", ".join(f"{k} {a[k].shape}" for k in LAYER_KEYS)
        raise WeightsError(path, f"material {name!r}: not a 6-input, 3-output Neural-BRDF network ({got})")
    for k, v in a.items():
        if not np.isfinite(v).all():
            raise WeightsError(path, f"material {name!r}: {int((~np.isfinite(v)).sum())} non-finite value(s) in {k}")
    return Network(name, *(np.asarray(a[k], dtype=np.float32) for k in LAYER_KEYS), source=os.fspath(path))


# --- reading -----------------------------------------------------------------------------


def _npz_groups(path):
    from ..limits import MAX_NBRDF_BYTES, MAX_NBRDF_MEMBERS
    from .safeio import UnsafePath, load_npz

    # The one input opener: a regular file within the size bound, its zip directory checked
    # before anything is inflated, numbers only (no pickles).
    try:
        arrays = load_npz(path, MAX_NBRDF_BYTES, "Neural-BRDF weights file", max_members=MAX_NBRDF_MEMBERS)
    except UnsafePath as exc:
        raise WeightsError(path, exc.fault) from None
    groups: dict[str, dict] = {}
    for key, arr in arrays.items():
        prefix, _, leaf = key.rpartition("/")
        if leaf in LAYER_KEYS:
            groups.setdefault(prefix, {})[leaf] = arr
    return groups


def _read_npy(path):
    import io

    from ..limits import MAX_NBRDF_BYTES
    from .safeio import UnsafePath, read_input

    try:
        data = read_input(path, MAX_NBRDF_BYTES, "Neural-BRDF weights file")
    except UnsafePath as exc:
        raise WeightsError(path, exc.fault) from None
    try:
        return np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 - numpy raises many kinds for bad bytes
        raise WeightsError(path, f"not a readable .npy ({_why(exc)})") from None


def _npy_groups(folder):
    inverse = {v: k for k, v in _NPY_KEYS.items()}
    groups: dict[str, dict] = {}
    try:
        entries = sorted(os.listdir(folder))
    except OSError as exc:
        raise WeightsError(folder, f"cannot list folder ({exc.strerror or exc})") from None
    for fname in entries:
        if not fname.endswith(".npy"):
            continue
        stem = fname[:-4]
        for leaf, key in inverse.items():
            if stem == leaf or stem.endswith("_" + leaf):
                prefix = stem[: -len(leaf)].rstrip("_")
                arr = _read_npy(os.path.join(folder, fname))
                groups.setdefault(prefix, {})[key] = arr
                break
    return groups


def _h5_groups(path):
    try:
        import h5py
    except ImportError:
        raise WeightsError(
            path,
            "reading Keras .h5 files needs the h5py package (not installed); "
            "convert with the Neural-BRDF project's h5_to_npy.py, or use an .npz",
        ) from None
    from ..limits import MAX_NBRDF_BYTES
    from .safeio import UnsafePath, open_input

    try:  # regular file within the bound (a FIFO would hang h5py); h5py then reads it itself
        open_input(path, MAX_NBRDF_BYTES, "Keras weights file").close()
    except UnsafePath as exc:
        raise WeightsError(path, exc.fault) from None
    datasets = {}
    try:
        with h5py.File(path, "r") as f:

            def visit(name, obj):
                if isinstance(obj, h5py.Dataset):
                    datasets[name] = np.asarray(obj[()])

            f.visititems(visit)
    except (OSError, ValueError) as exc:
        raise WeightsError(path, f"not a readable HDF5 file ({_why(exc)})") from None
    base = os.path.basename(os.fspath(path))
    return {os.path.splitext(base)[0]: dense_layers(datasets, path)}


def dense_layers(datasets: dict, path=None) -> dict:
    """W1 b1 .. W3 b3 from the datasets of a Keras file, ``{"group/name": array}``.

    Any Keras layout (save_weights, a whole model, Keras 3 .weights.h5 with datasets "0", "1"):
    a dense layer is a group holding one 2-D kernel and one 1-D bias of its width.
    """
    by_group: dict[str, list] = {}
    for name, arr in datasets.items():
        # A whole model's file also holds the optimizer's slots, shaped like the weights.
        if arr.ndim in (1, 2) and "optimizer" not in name.lower():
            by_group.setdefault(name.rpartition("/")[0], []).append(arr)
    layers = []
    for arrays in by_group.values():
        kernels = [a for a in arrays if a.ndim == 2]
        biases = [a for a in arrays if a.ndim == 1]
        if len(kernels) == 1 and len(biases) == 1 and biases[0].shape[0] == kernels[0].shape[1]:
            layers.append((kernels[0], biases[0]))
    if len(layers) != 3:
        raise WeightsError(path, f"expected 3 dense layers (a kernel and a bias each), found {len(layers)}")
    # Order the layers by the chain of shapes (6 -> h1 -> h2 -> 3), not by names, which Keras
    # numbers per session (dense_4, dense_5, ...).
    import itertools

    chains = [
        p
        for p in itertools.permutations(layers)
        if p[0][0].shape[0] == 6
        and p[2][0].shape[1] == 3
        and p[0][0].shape[1] == p[1][0].shape[0]
        and p[1][0].shape[1] == p[2][0].shape[0]
    ]
    if not chains:
        raise WeightsError(path, "the dense layers do not chain 6 -> ... -> 3")
    arrays = {}
    for i, (kernel, bias) in enumerate(chains[0], start=1):
        arrays[f"W{i}"], arrays[f"b{i}"] = kernel, bias
    return arrays


def _groups(path):
    path = os.fspath(path)
    if os.path.isdir(path):
        groups = _npy_groups(path)
        kind = "folder of Neural-BRDF .npy weights (NAME_fc1.npy ...)"
    else:
        if not os.path.exists(path):
            raise WeightsError(path, "no such file")
        low = path.lower()
        if low.endswith((".h5", ".hdf5")):
            return _h5_groups(path)
        groups = _npz_groups(path)
        kind = ".npz of Neural-BRDF weights (keys W1 b1 ... or NAME/W1 ...)"
    groups = {k: v for k, v in groups.items()}
    if not groups:
        if os.path.isdir(path):
            raise WeightsError(
                path,
                "a folder with no network weights in it (Neural-BRDF NAME_fc1.npy ...); "
                "choose a MERL .binary file or a weights file",
            )
        raise WeightsError(path, f"no network weights found; expected a {kind}")
    if "" in groups:
        # One unnamed material: name it after the file or folder.
        base = os.path.basename(os.path.normpath(path))
        groups[os.path.splitext(base)[0] or "material"] = groups.pop("")
    return groups


def list_materials(path) -> list[str]:
    """Names of the materials in a weights source (sorted)."""
    return sorted(_groups(path))


def load_network(path, name: str | None = None) -> Network:
    """One material's network. ``name`` may be omitted when the source holds a single one."""
    groups = _groups(path)
    if name is None:
        if len(groups) != 1:
            raise WeightsError(
                path, f"holds {len(groups)} materials; choose one as FILE:NAME, e.g. {_names(sorted(groups)[:4])}, ..."
            )
        name = next(iter(groups))
    if name not in groups:
        import difflib

        close = difflib.get_close_matches(name, sorted(groups), n=4, cutoff=0.5) or sorted(groups)[:4]
        raise WeightsError(path, f"no material {name!r}; it has {len(groups)}, e.g. {_names(close)}")
    return _network(path, name, groups[name])


# --- evaluation --------------------------------------------------------------------------


def _axis_centres():
    th = ((np.arange(RES_TH) + 0.5) / RES_TH) ** 2 * HALF_PI
    td = (np.arange(RES_TD) + 0.5) / RES_TD * HALF_PI
    pd = (np.arange(RES_PD) + 0.5) / RES_PD * np.pi
    return th, td, pd


def valid_cells():
    """Flat mask of the cells whose two directions are both above the horizon (at the centre).

    With phi_h = 0, z of the incoming and outgoing directions are
    cos td cos th -/+ sin td cos pd sin th (the rotation of the difference vector by th).
    """
    th, td, pd = _axis_centres()
    a = np.cos(td)[None, :, None] * np.cos(th)[:, None, None]
    b = np.sin(td)[None, :, None] * np.cos(pd)[None, None, :] * np.sin(th)[:, None, None]
    return ((a - b > 0.0) & (a + b > 0.0)).ravel()


def forward(net: Network, x: np.ndarray) -> np.ndarray:
    """BRDF (n, 3) of input rows x (n, 6), float32 throughout, in chunks of CHUNK rows."""
    x = np.asarray(x, dtype=np.float32)
    out = np.empty((x.shape[0], 3), dtype=np.float32)
    for s in range(0, x.shape[0], CHUNK):
        h = x[s : s + CHUNK] @ net.W1
        h += net.b1
        np.maximum(h, 0.0, out=h)
        h = h @ net.W2
        h += net.b2
        np.maximum(h, 0.0, out=h)
        y = h @ net.W3
        y += net.b3
        out[s : s + CHUNK] = y
    # exp in float64: a large log-value must give a large finite number, not float32 inf.
    with np.errstate(over="ignore"):
        val = np.expm1(out.astype(np.float64))
    return np.maximum(val, 0.0)


def decode(net: Network, path=None) -> MerlTable:
    """The network tabulated at the MERL cell centres (module docstring); below-horizon cells missing."""
    th, td, pd = _axis_centres()
    ok = valid_cells()
    idx = np.flatnonzero(ok)
    rho = np.zeros((3, N_CELLS))
    sth, cth = np.sin(th).astype(np.float32), np.cos(th).astype(np.float32)
    std, ctd = np.sin(td), np.cos(td)
    dx = (std[:, None] * np.cos(pd)[None, :]).astype(np.float32).ravel()
    dy = (std[:, None] * np.sin(pd)[None, :]).astype(np.float32).ravel()
    dz = np.repeat(ctd.astype(np.float32), RES_PD)
    plane = RES_TD * RES_PD
    # Build the inputs one chunk of valid cells at a time: memory stays bounded.
    step = CHUNK * 4
    for s in range(0, idx.size, step):
        cells = idx[s : s + step]
        ith, rest = np.divmod(cells, plane)
        x = np.empty((cells.size, 6), dtype=np.float32)
        x[:, 0] = sth[ith]
        x[:, 1] = 0.0
        x[:, 2] = cth[ith]
        x[:, 3] = dx[rest]
        x[:, 4] = dy[rest]
        x[:, 5] = dz[rest]
        rho[:, cells] = forward(net, x).T
    src = path if path is not None else net.source
    bad = ~np.isfinite(rho) | (rho > MAX_REFLECTANCE)
    if bad.any():
        raise WeightsError(
            src,
            f"material {net.name!r}: the network gives {int(bad.sum())} value(s) "
            f"beyond any reflectance (> {MAX_REFLECTANCE:g})",
        )
    valid = np.broadcast_to(ok, (3, N_CELLS)).copy()
    return MerlTable(rho, valid, os.fspath(src) if src is not None else None, label=net.name)


def read_table(spec, material: str | None = None) -> MerlTable:
    """A material source as a MERL table: a MERL file, or a network (``FILE:NAME`` or ``material``).

    The one entry point for the command line and the extension; faults are ``MerlError``.
    """
    from .merl import read_merl

    path, name = parse_source(spec)
    name = material or name
    if is_weights_source(path):
        return decode(load_network(path, name))
    if name is not None:
        raise MerlError(
            path,
            f"a material name ({name!r}) was given, but this is not a weights file (.npz, .h5 or a folder of .npy)",
        )
    return read_merl(path)


def _npy_material(path):
    """(folder, material) for one ``NAME_fc1.npy``-style file of a weights folder, else None."""
    folder, fname = os.path.split(os.fspath(path))
    stem = fname[:-4] if fname.endswith(".npy") else None
    if stem is None:
        return None
    for leaf in _NPY_KEYS.values():
        if stem == leaf or stem.endswith("_" + leaf):
            return folder or ".", stem[: -len(leaf)].rstrip("_") or None
    return None


def chooser_materials(path) -> list[str]:
    """Materials offered for a path picked in a file browser ([] for a MERL file or a fault)."""
    path = os.fspath(path)
    picked = _npy_material(path)
    if picked:
        path = picked[0]
    if not path or not is_weights_source(path) or not os.path.exists(path):
        return []
    try:
        return list_materials(path)
    except MerlError:
        return []


def source_spec(path, material: str | None = None) -> str:
    """The source spec (a MERL path, or ``FILE:NAME``) of a path picked in a file browser.

    A ``.npy`` of a weights folder stands for its material in that folder; a weights set with
    several materials needs ``material``. Faults are ``MerlError``s naming the file.
    """
    path = os.fspath(path)
    picked = _npy_material(path)
    if picked:
        path, material = picked[0], material or picked[1]
    if not is_weights_source(path):
        return path
    net = load_network(path, material or None)
    return f"{path}:{net.name}"
