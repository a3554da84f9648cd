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
    config.addinivalue_line(
        "markers",
        "blender: needs Blender (the bpy module, a blender binary or its "
        "builder); scripts/test.sh --fast runs the tests without it",
    )


def pytest_collection_modifyitems(config, items):
    # A test using the bpy fixture (directly or through another fixture) is a Blender test,
    # whatever its file says: the fast lane then never starts Blender by accident.
    for item in items:
        if "blender" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.blender)


@pytest.fixture(scope="session")
def sample_table():
    import samples
    from addon.core.file.merl import read_merl

    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = read_merl(samples.sample_path(name))
        return cache[name]

    return get


@pytest.fixture(scope="session")
def views():
    return np.radians(np.arange(0.0, 90.0, 1.0))


@pytest.fixture(scope="session")
def blender(tmp_path_factory):
    """The bpy module with this repository enabled as an extension (bl_ext.bmtest.brdf_moments).

    Session-wide: an extension repository can be added once per process."""
    os.environ.setdefault("BLENDER_USER_RESOURCES", str(tmp_path_factory.mktemp("blender-user")))
    from addon.wheel import import_bpy

    bpy = import_bpy()  # bpy first (it puts addon_utils on the path), with OSL reachable

    repo = tmp_path_factory.mktemp("ext-repo")
    os.symlink(ROOT, repo / "brdf_moments")
    bpy.context.preferences.extensions.repos.new(
        name="bmtest", module="bmtest", custom_directory=str(repo), source="USER"
    )
    import addon_utils

    addon_utils.enable("bl_ext.bmtest.brdf_moments", default_set=True)
    assert hasattr(bpy.types.Material, "brdf_moments")
    yield bpy
    addon_utils.disable("bl_ext.bmtest.brdf_moments", default_set=True)


@pytest.fixture
def fresh(blender):
    """An empty scene (read_factory_settings would disable the extension)."""
    blender.ops.wm.read_homefile(use_empty=True)
    return blender


@pytest.fixture(scope="session")
def stress_log():
    """Outcomes of the stress cases, by category; written as JSON at the end of the session
    when BRDF_MOMENTS_STRESS_SUMMARY names a file (scripts/stress_report.py does)."""
    from _stress import StressLog

    log = StressLog()
    yield log
    target = os.environ.get("BRDF_MOMENTS_STRESS_SUMMARY")
    if target:
        log.write(target)
