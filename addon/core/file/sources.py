"""Material sources as the user names them: a MERL file, or a Neural-BRDF network.

A source is a path, or ``FILE:NAME`` for one material of a weights set. Telling the two
apart needs only the path, never the decoder: ``names`` (a material's name) and ``nbrdf``
(the decoder itself) both read sources through this module, which imports neither.
"""

from __future__ import annotations

import os

WEIGHT_SUFFIXES = (".npz", ".h5", ".hdf5")


def is_weights_source(path) -> bool:
    """Whether ``path`` looks like a Neural-BRDF source (by suffix or folder), not a MERL file."""
    path = os.fspath(path)
    return os.path.isdir(path) or path.lower().endswith(WEIGHT_SUFFIXES)


def parse_source(spec: str):
    """Split ``FILE:NAME`` into (FILE, NAME) when FILE is a weights source; else (spec, None).

    A plain path wins: a file literally named ``a.npz:x`` is read as that file.
    """
    spec = os.fspath(spec)
    if os.path.exists(spec):
        return spec, None
    head, sep, tail = spec.rpartition(":")
    if sep and head and tail and is_weights_source(head):
        return head, tail
    return spec, None


def source_exists(spec) -> bool:
    """Whether the file (or folder) behind a source spec is there."""
    return os.path.exists(parse_source(spec)[0])


def source_file(spec) -> str:
    """The file (or folder) behind a source spec: ``FILE`` of ``FILE:NAME``, else the spec."""
    return parse_source(spec)[0]
