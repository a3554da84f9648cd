#!/usr/bin/env bash
# Set up, then run the main job on the built-in sample; results go to out/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
PY=.venv/bin/python
sample=$($PY -m samples ggx_glossy)
mkdir -p out
$PY -m addon profiles "$sample" --out out/ggx_glossy.profiles.json --plot out/ggx_glossy.profiles.png
echo "demo: done; see out/"
