"""Build the two installable archives into dist/ (or the folder given):

- ``brdf_moments-<version>.zip``: the extension, built by Blender's own builder
  (``blender_ext.py build``, found in the bpy wheel), bundling the scipy wheel;
- ``brdf_moments-<version>-legacy.zip``: the same files under a ``brdf_moments/`` folder,
  without the wheel, for Blender 3.4-4.1 (Preferences > Add-ons > Install); there scipy
  comes from the system Python (Debian: python3-scipy).

Usage: .venv/bin/python scripts/package.py [OUT_DIR]
"""

import glob
import os
import subprocess
import sys
import tomllib
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def blender_ext_tool():
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.origin:
        raise SystemExit("package: the bpy module is needed for Blender's extension builder (run scripts/setup.sh)")
    # <bpy>/<major.minor>/scripts/...: found by glob, so any bpy version's builder serves.
    pattern = os.path.join(os.path.dirname(spec.origin), "[0-9]*.[0-9]*", "scripts", "addons_core", "bl_pkg", "cli",
                           "blender_ext.py")
    hits = sorted(glob.glob(pattern))
    if not hits:
        raise SystemExit(f"package: {pattern} not found")
    return hits[-1]


def build(out_dir):
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as fh:
        manifest = tomllib.load(fh)
    missing = [w for w in manifest.get("wheels", []) if not os.path.isfile(os.path.join(ROOT, w))]
    if missing:
        raise SystemExit(f"package: wheel(s) missing, run scripts/setup.sh first: {', '.join(missing)}")
    os.makedirs(out_dir, exist_ok=True)
    ext = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}.zip")
    for path in (ext,):
        if os.path.exists(path):
            os.unlink(path)  # the builder refuses to overwrite
    subprocess.run([sys.executable, blender_ext_tool(), "build", "--source-dir", ROOT, "--output-filepath", ext],
                   check=True, stdout=subprocess.DEVNULL)
    legacy = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}-legacy.zip")
    tmp = legacy + ".part"
    with zipfile.ZipFile(ext) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            if info.filename.startswith("wheels/") or info.is_dir():
                continue
            dst.writestr(f"{manifest['id']}/{info.filename}", src.read(info))
    os.replace(tmp, legacy)
    return ext, legacy


if __name__ == "__main__":
    for path in build(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "dist")):
        print(path)
