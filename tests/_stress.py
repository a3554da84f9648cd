"""Helpers shared by the stress suite (tests/test_stress_*.py)."""

from __future__ import annotations

import hashlib
import json
import math
import os
import struct
import subprocess
import sys
from collections import defaultdict

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# What a case ended in. "error": refused with a clear message; "clamped": a finite result
# with something clamped, flagged or reported as undefined (null); "valid": a finite result
# checked against a closed form, an invariance or an independent computation.
OUTCOMES = ("error", "clamped", "valid")


class StressLog:
    def __init__(self):
        self.cases = defaultdict(lambda: defaultdict(int))
        self.examples = defaultdict(list)

    def record(self, category: str, outcome: str, case: str = ""):
        assert outcome in OUTCOMES, outcome
        self.cases[category][outcome] += 1
        if case and len(self.examples[category]) < 40:
            self.examples[category].append(f"{case}: {outcome}")

    def write(self, path):
        data = {cat: {"counts": dict(c), "examples": self.examples[cat]} for cat, c in sorted(self.cases.items())}
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        with open(path, "w") as fh:
            json.dump(data, fh, indent=1, sort_keys=True)


def sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def assert_finite_tree(obj, where="result"):
    """Every number in a nested dict/list/array is finite; None (undefined) is allowed."""
    if obj is None or isinstance(obj, (str, bool)):
        return
    if isinstance(obj, dict):
        for k, v in obj.items():
            assert_finite_tree(v, f"{where}.{k}")
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            assert_finite_tree(v, f"{where}[{i}]")
    elif isinstance(obj, np.ndarray):
        if obj.dtype.kind in "fc":
            assert np.isfinite(obj).all(), f"non-finite values in {where}"
        elif obj.dtype == object:
            assert_finite_tree(list(obj.ravel()), where)
    elif isinstance(obj, (int, np.integer)):
        return
    elif isinstance(obj, (float, np.floating)):
        assert math.isfinite(obj), f"{where} = {obj}"
    else:
        raise AssertionError(f"unexpected {type(obj).__name__} in {where}")


def assert_profiles_sane(prof):
    """Profiles hold finite numbers or NaN (undefined, exported as null), never inf, and
    respect what every distribution satisfies: alpha >= 0, means inside the domain, variances
    >= 0, |correlation| <= 1, kurtosis >= 1 + skewness^2 (excess >= skew^2 - 2)."""
    half = math.pi / 2
    for ch in ("r", "g", "b", "avg"):
        p = prof[ch]
        for k, v in p.items():
            v = np.asarray(v, float)
            assert not np.isinf(v).any(), f"{ch}.{k} has inf"
        a = np.asarray(p["alpha"], float)
        assert np.all(np.isfinite(a) & (a >= 0)), f"{ch}.alpha"
        defined = a > 0
        if not defined.any() or "mu_theta" not in p:
            continue
        mt = np.asarray(p["mu_theta"])[defined]
        mt = mt[np.isfinite(mt)]
        assert np.all(np.abs(mt) <= half + 1e-9), f"{ch}.mu_theta outside the domain"
        if "sigma_tt" not in p:
            continue
        stt, spp, stp = (np.asarray(p[k])[defined] for k in ("sigma_tt", "sigma_pp", "sigma_tp"))
        ok = np.isfinite(stt) & np.isfinite(spp)
        assert np.all(stt[ok] >= 0) and np.all(spp[ok] >= 0)
        assert np.all(stt[ok] <= half**2 + 1e-9) and np.all(spp[ok] <= half**2 + 1e-9)
        assert np.all(stp[ok] ** 2 <= stt[ok] * spp[ok] * (1 + 1e-6) + 1e-18), f"{ch}: |correlation| > 1"
        if "kurt_40" in p:
            for s_key, k_key in (("skew_30", "kurt_40"), ("skew_03", "kurt_04")):
                s, k = np.asarray(p[s_key])[defined], np.asarray(p[k_key])[defined]
                fine = np.isfinite(s) & np.isfinite(k)
                assert np.all(k[fine] >= s[fine] ** 2 - 2 - 1e-4), f"{ch}.{k_key} below the kurtosis bound"


def run_cli(*args, cwd=ROOT, timeout=300):
    """``python -m addon ...`` as a subprocess: arguments as a list, never through a shell.

    From another ``cwd`` (to see what a command would create there) the repository goes on
    PYTHONPATH so that ``-m addon`` still finds the package."""
    env = dict(os.environ)
    if os.path.abspath(cwd) != ROOT:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [ROOT, env.get("PYTHONPATH")]))
    return subprocess.run(
        [sys.executable, "-m", "addon", *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )


def assert_one_line_error(res, *fragments, progress=None):
    """Exit code 2, one line on stderr containing every fragment, no traceback.

    ``progress``: a prefix of progress lines the command may also print on stderr
    ('analyze' reports "analysing: k/n"); they are not error lines."""
    assert res.returncode == 2, (res.returncode, res.stdout, res.stderr)
    lines = [ln for ln in res.stderr.strip().splitlines() if not (progress and ln.startswith(progress))]
    assert len(lines) == 1, res.stderr
    assert "Traceback" not in res.stderr
    for f in fragments:
        assert str(f) in lines[0], (f, lines[0])
    return lines[0]


def stored_of(raw: bytes) -> np.ndarray:
    """The (3, N) stored float64 values of a MERL file's bytes (a writable copy)."""
    return np.frombuffer(raw[12:], dtype="<f8").reshape(3, -1).copy()


def merl_bytes(stored: np.ndarray, header=(90, 90, 180)) -> bytes:
    return np.asarray(header, dtype="<i4").tobytes() + np.ascontiguousarray(stored, dtype="<f8").tobytes()


def exr_bytes(width, height, compression=3, body=b""):
    """A scanline OpenEXR header (RGB float) claiming ``width`` x ``height``, its chunk table
    pointing into ``body``: enough for a decoder to start allocating what the header says."""

    def attr(name, kind, value):
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value

    chans = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in "BGR") + b"\0"
    box = struct.pack("<4i", 0, 0, width - 1, height - 1)
    head = (
        b"\x76\x2f\x31\x01"
        + struct.pack("<I", 2)
        + attr("channels", "chlist", chans)
        + attr("compression", "compression", bytes([compression]))
        + attr("dataWindow", "box2i", box)
        + attr("displayWindow", "box2i", box)
        + attr("lineOrder", "lineOrder", b"\0")
        + attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
        + attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
        + attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
        + b"\0"
    )
    chunks = -(-height // {0: 1, 3: 16}[compression])
    start = len(head) + 8 * chunks
    body = body or bytes(max(16, chunks * 16))
    offsets = [start + (i * 16) % max(len(body) - 16, 1) for i in range(chunks)]
    return head + struct.pack(f"<{chunks}Q", *offsets) + body


def build_operator_in_memory(theta_o):
    """The slice operator built whole in memory, without the cache: what the streamed cache
    (``integrate.get_operator``) must hold."""
    from addon.core.profiles.integrate import SliceOperator, _build_chunks
    from addon.core.profiles.quadrature import RuleParams

    theta_o = np.asarray(theta_o, dtype=float)
    parts, offsets = _build_chunks(theta_o, RuleParams(), None)
    return SliceOperator(theta_o, offsets, **{k: np.concatenate(v) for k, v in parts.items()})
