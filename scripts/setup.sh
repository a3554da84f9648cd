#!/usr/bin/env bash
# Set up everything: .venv with the engine, the tests and the bpy module; .venv-bpy50 with
# the same pins but bpy 5.0 (the third lane); the scipy wheel the extension bundles; Debian's
# blender for the `blender -b` lane, and Xvfb + xdotool + ImageMagick for the windowed lane.
# Idempotent: a second run only checks. Needs Python 3.11 (bpy 4.5 and 5.0 wheels are cp311).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
if ! "$PY" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    echo "setup: Python 3.11 is required (found $("$PY" --version 2>&1))" >&2
    exit 1
fi
stamp=.venv/.requirements.sha
want=$(sha256sum requirements.txt | cut -d' ' -f1)
if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv" >&2
    "$PY" -m venv .venv
fi
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    echo "setup: installing Python packages (bpy is a ~370 MB wheel; first time takes a minute)" >&2
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -r requirements.txt
    echo "$want" > "$stamp"
fi

# Lane 3: the same pins with bpy 5.0.1 in its own venv (pip's cache serves the shared wheels).
BPY50=5.0.1
stamp50=.venv-bpy50/.requirements.sha
want50=$(printf '%s %s' "$want" "$BPY50" | sha256sum | cut -d' ' -f1)
if [ ! -x .venv-bpy50/bin/python ]; then
    echo "setup: creating .venv-bpy50" >&2
    "$PY" -m venv .venv-bpy50
fi
if [ "$(cat "$stamp50" 2>/dev/null)" != "$want50" ]; then
    echo "setup: installing the bpy $BPY50 lane's packages (another ~400 MB wheel)" >&2
    req50=$(mktemp)
    sed "s/^bpy==.*/bpy==$BPY50/" requirements.txt > "$req50"
    .venv-bpy50/bin/python -m pip install -q --upgrade pip
    .venv-bpy50/bin/python -m pip install -q -r "$req50"
    rm -f "$req50"
    echo "$want50" > "$stamp50"
fi

# The wheels the manifest lists (bundled into the extension zip by scripts/package.py).
.venv/bin/python - <<'PYEOF'
import os, subprocess, sys, tomllib
with open("blender_manifest.toml", "rb") as fh:
    wheels = tomllib.load(fh).get("wheels", [])
for wheel in wheels:
    if os.path.isfile(wheel):
        continue
    name = os.path.basename(wheel)
    dist, version = name.split("-")[:2]
    print(f"setup: fetching {name}", file=sys.stderr)
    subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--only-binary=:all:", "--no-deps",
                    "--platform", "manylinux_2_28_x86_64", "--python-version", "3.11",
                    "-d", os.path.dirname(wheel), f"{dist}=={version}"], check=True)
    if not os.path.isfile(wheel):
        sys.exit(f"setup: pip fetched another file than {name}; update the manifest's wheels")
PYEOF

# Debian's Blender 3.4 (no OSL) runs the second test lane, as a legacy add-on.
if ! command -v blender >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "setup: installing Debian's blender for the blender -b lane (about a minute)" >&2
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq >/dev/null
        apt-get install -y -qq --no-install-recommends blender python3-numpy python3-scipy >/dev/null
    else
        echo "setup: no blender and no root apt-get: the blender -b test lane cannot run here" >&2
    fi
fi

# The windowed lane: Blender 3.4 in a virtual X server, real key presses, screenshots.
if ! command -v xvfb-run >/dev/null 2>&1 || ! command -v xdotool >/dev/null 2>&1 || ! command -v import >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "setup: installing xvfb, xdotool and imagemagick for the windowed lane" >&2
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq >/dev/null
        apt-get install -y -qq --no-install-recommends xvfb xauth xdotool imagemagick >/dev/null
    else
        echo "setup: no xvfb/xdotool and no root apt-get: the windowed test lane cannot run here" >&2
    fi
fi
