#!/usr/bin/env bash
# Set up, then run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export BRDF_MOMENTS_CACHE=${BRDF_MOMENTS_CACHE:-$PWD/.cache/engine}
.venv/bin/python -m pytest -q tests "$@"
