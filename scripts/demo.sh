#!/usr/bin/env bash
# Set up, then run the main job on the built-in sample through the extension's operators:
# analyse, edit, export, and render the measured | edited preview; results go to out/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python samples/demo.py --out out "$@"
echo "demo: done; see out/"
