"""The live preview's work, without Blender: what a slider move computes (SPEC §4).

A draft synthesis of the edit (``edit(..., draft=True)``: a quick, rougher solve) baked at a
quarter of the sphere's resolution is the first image; the full synthesis (the table Apply
writes) baked at full resolution replaces it. The panel's worker thread (``blender.live``)
runs ``work`` and writes each image into the preview; ``bench --only live`` times the same.
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

FINAL_SAMPLES = 128  # Build Preview's bake: within 5 % per pixel on the near-mirror (BENCHMARKS.md)
LIVE_DIAMETER_DIV = 4  # the first live image: a quarter of the sphere's resolution
LIVE_SAMPLES = 16


def fast_edit(table, targets, prof, fit, draft=False, region=None, keep=False, stop=None):
    """The edit's synthesis, not re-measured: what a slider drag can afford (``draft``: the
    quick, rougher solve shown first; ``keep``: remembered for an Apply of the same sliders;
    ``stop()``: give up between steps, raising ``edit.Superseded``)."""
    from ..edit import edit

    return edit(table, targets, prof, fit, remeasure=False, draft=draft, region=region, keep=keep, stop=stop).table


def _profiles_key(prof, fit, mode):
    h = hashlib.sha1(repr((fit.get("mu_slope"), fit.get("sigma2"), mode)).encode())
    h.update(np.ascontiguousarray(prof.theta_o, "<f8").tobytes())
    for key in ("alpha", "mu_theta", "sigma_tt", "sigma_pp"):
        h.update(np.ascontiguousarray(prof["avg"][key], "<f8").tobytes())
    return h.hexdigest()


_REGIONS = {}  # the reachable region of the material being dragged: once, not per move


def region_for(prof, fit, mode):
    """The material's reachable region, computed once per analysis (by content, not identity:
    the panel unpacks a new Profiles object for every move)."""
    from ..edit.reach import reachable_region

    key = _profiles_key(prof, fit, mode)
    if key not in _REGIONS:
        _REGIONS.clear()
        _REGIONS[key] = reachable_region(prof, fit, mode=mode)
    return _REGIONS[key]


_TABLES = {}  # (path, mtime, size) -> MerlTable: the source stays in memory between drags


def source_table(path):
    from ..file.nbrdf import read_table
    from ..file.sources import source_file

    st = os.stat(source_file(path))  # a MERL file, or the FILE of FILE:NAME (a network)
    key = (path, st.st_mtime_ns, st.st_size)
    if key not in _TABLES:
        _TABLES.clear()
        _TABLES[key] = read_table(path)
    return _TABLES[key]


def work(table, targets, prof, fit, env, diameter, stale=lambda: False, post=lambda stage, rgb, cov: None, region=None):
    """The draft image, then the refined one, each handed to ``post(stage, rgb, cov)``
    ('live', then 'refined'); stops early when ``stale()`` says a newer move came. ``region``:
    the material's stored reachable region (else computed once here). The full synthesis is
    kept (``edit(..., keep=True)``): an Apply of the same sliders writes it without solving again."""
    from ..edit import Superseded
    from ..limits import check
    from . import TableBRDF, bake_sphere

    diameter = check("diameter", diameter)
    region = region if region is not None else region_for(prof, fit, targets.mode)
    try:
        # A synthesis made moot (a newer move, an Apply) stops at its next step, not at the end
        # of its stage: a drag otherwise leaves several syntheses sharing the two cores.
        new = fast_edit(table, targets, prof, fit, draft=True, region=region, stop=stale)
        if stale():
            return
        rgb, cov = bake_sphere(TableBRDF(new, prof), env, max(diameter // LIVE_DIAMETER_DIV, 8), LIVE_SAMPLES, 0)
        if stale():  # made moot while baking: nothing is posted once stale (unregister, a newer move)
            return
        post("live", rgb, cov)
        if stale():
            return
        new = fast_edit(table, targets, prof, fit, region=region, keep=True, stop=stale)
    except Superseded:
        return
    if stale():
        return
    rgb, cov = bake_sphere(TableBRDF(new, prof), env, diameter, FINAL_SAMPLES, 0)
    if not stale():
        post("refined", rgb, cov)
