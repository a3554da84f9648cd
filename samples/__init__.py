"""Sample materials: analytic BRDFs and measured Neural-BRDF networks, made into MERL files on demand.

Tables are 35 MB each, so they are made when first asked for and cached in the
git-ignored ``samples/.cache`` (or ``$BRDF_MOMENTS_SAMPLES``). Tabulation is deterministic:
the same name always gives the same bytes.

Measured materials are named ``SET/NAME``: ``rgl/NAME`` (51 isotropic materials of the RGL
database, EPFL) and ``nielsen/NAME`` (8 of Nielsen, Jensen and Ramamoorthi 2015), decoded
from the pre-trained networks of Sztrajman, Rainer, Ritschel and Weyrich 2021 (MIT licence,
``samples/measured/``). Their tables are cached under a hash of the weights
(``measured/HASH/rgl-NAME.binary``), so a changed weights file decodes afresh.
"""

from __future__ import annotations

import os

from .analytic import GGX, Lambertian, Phong

CATALOG = {
    "lambertian": Lambertian(albedo=(0.8, 0.8, 0.8)),
    "phong": Phong(kd=(0.1, 0.1, 0.1), ks=(0.5, 0.5, 0.5), exponent=200.0),
    "ggx_mirror": GGX(roughness=0.02, f0=(0.95, 0.95, 0.95), kd=(0.01, 0.01, 0.01)),
    "ggx_glossy": GGX(roughness=0.1, f0=(0.04, 0.04, 0.04), kd=(0.15, 0.15, 0.15)),
    "ggx_rough": GGX(roughness=0.5, f0=(0.04, 0.04, 0.04), kd=(0.2, 0.2, 0.2)),
    "gold": GGX(roughness=0.08, f0=(1.0, 0.78, 0.34), kd=(0.0, 0.0, 0.0)),
    "red_plastic": GGX(roughness=0.2, f0=(0.04, 0.04, 0.04), kd=(0.5, 0.05, 0.05)),
}

DEFAULT = "ggx_glossy"


def synthetic_set(n: int, seed: int = 0):
    """``n`` varied analytic materials (name, brdf) for database-scale tests and benchmarks."""
    import numpy as np

    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        rough = float(np.exp(rng.uniform(np.log(0.03), np.log(0.6))))
        metal = rng.uniform() < 0.4
        if metal:
            f0 = tuple(float(v) for v in rng.uniform(0.5, 1.0, 3))
            kd = (0.0, 0.0, 0.0)
        else:
            f0 = (0.04, 0.04, 0.04)
            kd = tuple(float(v) for v in rng.uniform(0.02, 0.6, 3))
        if rng.uniform() < 0.15:
            model = Phong(
                kd=kd,
                ks=tuple(float(v) for v in rng.uniform(0.2, 0.8, 3)),
                exponent=float(np.exp(rng.uniform(np.log(10), np.log(2000)))),
            )
        else:
            model = GGX(roughness=rough, f0=f0, kd=kd)
        out.append((f"synthetic_{i:03d}", model))
    return out


def cache_dir() -> str:
    here = os.path.dirname(os.path.abspath(__file__))
    return os.environ.get("BRDF_MOMENTS_SAMPLES") or os.path.join(here, ".cache")


MEASURED_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "measured")
# Prefix of a measured set -> its weights file in samples/measured/.
MEASURED_SETS = {
    "rgl": "nbrdf-rgl-isotropic.npz",
    "nielsen": "nbrdf-nielsen.npz",
}


def measured_names() -> list[str]:
    """All measured materials, ``SET/NAME`` (the 51 RGL and 8 Nielsen networks)."""
    from addon.core.file.nbrdf import list_materials

    return [
        f"{prefix}/{name}"
        for prefix, fname in MEASURED_SETS.items()
        for name in list_materials(os.path.join(MEASURED_DIR, fname))
    ]


def measured_source(name: str):
    """(weights file, material key) of a measured sample name ``SET/NAME``."""
    prefix, sep, key = name.partition("/")
    if not sep or prefix not in MEASURED_SETS or not key:
        raise KeyError(
            f"unknown sample {name!r}; measured samples are named "
            f"{' or '.join(p + '/NAME' for p in MEASURED_SETS)} (see python -m samples --list)"
        )
    return os.path.join(MEASURED_DIR, MEASURED_SETS[prefix]), key


def _measured_path(name: str, force: bool) -> str:
    from addon.core.file.cachefs import verified, write_seal
    from addon.core.file.merl import write_merl
    from addon.core.file.nbrdf import WeightsError, decode, load_network

    weights, key = measured_source(name)
    try:
        net = load_network(weights, key)
    except WeightsError as exc:
        raise KeyError(f"unknown sample {name!r}: {exc}") from None
    # measured/<hash of the weights>/SET-NAME.binary: a clean material name for the table,
    # and changed weights land in another folder, so they are decoded afresh.
    root = os.path.join(cache_dir(), "measured")
    fname = name.replace("/", "-") + ".binary"
    path = os.path.join(root, net.digest(), fname)
    if force or not verified(path):  # sealed: a damaged or unsealed table is decoded again
        os.makedirs(os.path.dirname(path), exist_ok=True)
        write_merl(decode(net), path)
        write_seal(path)
        # Drop tables decoded from older weights of the same material: no leftovers.
        for digest in os.listdir(root):
            old = os.path.join(root, digest, fname)
            if digest != net.digest() and os.path.isfile(old):
                try:
                    os.remove(old)
                    if os.path.isfile(old + ".seal"):
                        os.remove(old + ".seal")
                    os.rmdir(os.path.dirname(old))  # only if now empty
                except OSError:
                    pass
    return path


def sample_path(name: str, force: bool = False) -> str:
    """Path of the named sample's MERL file, tabulating (or decoding) it first if needed."""
    from addon.core.file.cachefs import verified, write_seal
    from addon.core.file.merl import tabulate, write_merl

    if "/" in name:
        return _measured_path(name, force)
    if name not in CATALOG:
        raise KeyError(
            f"unknown sample {name!r}; known: {', '.join(sorted(CATALOG))}, "
            f"and measured SET/NAME (python -m samples --list)"
        )
    folder = cache_dir()
    if os.path.lexists(folder) and not os.path.isdir(folder):
        raise ValueError(f"{folder}: BRDF_MOMENTS_SAMPLES must name a folder, and this is not one")
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, f"{name}.binary")
    if force or not verified(path):
        write_merl(tabulate(CATALOG[name]), path)
        write_seal(path)
    return path
