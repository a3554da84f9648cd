import os
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

# Shared caches for the session: sample tables and slice operators are deterministic, so
# reusing them across runs only saves time. Tests that check the cache itself use tmp dirs.
os.environ.setdefault("BRDF_MOMENTS_CACHE", os.path.join(ROOT, ".cache", "engine"))
os.environ.setdefault("BRDF_MOMENTS_SAMPLES", os.path.join(ROOT, ".cache", "samples"))


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: takes more than a few seconds")
    config.addinivalue_line("markers", "stress: numerical-stability and bad-input suite")


@pytest.fixture(scope="session")
def sample_table():
    from addon.core.merl import read_merl
    import samples

    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = read_merl(samples.sample_path(name))
        return cache[name]

    return get


@pytest.fixture(scope="session")
def views():
    return np.radians(np.arange(0.0, 90.0, 1.0))
