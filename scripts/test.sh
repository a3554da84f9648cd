#!/usr/bin/env bash
# Set up, then run the whole test suite: the engine, lane 1 (the bpy 4.5 module, the
# repository loaded as an extension), lane 2 (Debian's blender -b 3.4, the packaged
# legacy add-on), lane 3 (the Blender tests again under the bpy 5.0 module, .venv-bpy50),
# the windowed lane (Blender 3.4 in a window under Xvfb, real key presses) and the stress
# suite. Every Blender lane must run: a missing one fails (BRDF_MOMENTS_REQUIRE_LANES).
#
# --fast: the engine alone, under a minute: no Blender (tests marked `blender`, and every
# test using the bpy fixture, see tests/conftest.py), no stress suite, no `slow` tests.
# Further arguments go to pytest in both modes; naming test files runs those alone.
set -euo pipefail
cd "$(dirname "$0")/.."
fast=0
if [ "${1:-}" = "--fast" ]; then
    fast=1
    shift
fi
bash scripts/setup.sh
export BRDF_MOMENTS_CACHE=${BRDF_MOMENTS_CACHE:-$PWD/.cache/engine}
# The whole of tests/ unless test files or folders are named (then only those).
where=(tests)
for arg in "$@"; do
    if [ -e "${arg%%::*}" ]; then
        where=()
    fi
done
if [ "$fast" = 1 ]; then
    exec .venv/bin/python -m pytest -q -m "not blender and not stress and not slow" "${where[@]}" "$@"
fi
export BRDF_MOMENTS_REQUIRE_LANES=1
.venv/bin/python -m pytest -q "${where[@]}" "$@"
