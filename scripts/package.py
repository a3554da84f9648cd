"""Build the two installable archives into dist/ (or the folder given):

- ``brdf_moments-<version>.zip``: the extension, built by Blender's own builder
  (``blender_ext.py build``, found in the bpy wheel), bundling the scipy wheel;
- ``brdf_moments-<version>-legacy.zip``: the same files under a ``brdf_moments/`` folder,
  without the wheel, for Blender 3.4-4.1 (Preferences > Add-ons > Install); there scipy
  comes from the system Python (Debian: python3-scipy).

What ships is the allow-list ``[build] paths`` of blender_manifest.toml (the builder adds the
manifest and the wheels). The legacy zip needs no wheel, so it is built even when the scipy
wheel has not been fetched; the extension zip is then skipped, with a warning.

Usage: .venv/bin/python scripts/package.py [OUT_DIR]
"""

import glob
import os
import subprocess
import sys
import tomllib
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = "blender_manifest.toml"


def blender_ext_tool():
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.origin:
        raise SystemExit("package: the bpy module is needed for Blender's extension builder (run scripts/setup.sh)")
    # <bpy>/<major.minor>/scripts/...: found by glob, so any bpy version's builder serves.
    pattern = os.path.join(
        os.path.dirname(spec.origin), "[0-9]*.[0-9]*", "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py"
    )
    hits = sorted(glob.glob(pattern))
    if not hits:
        raise SystemExit(f"package: {pattern} not found")
    return hits[-1]


def _drop_duplicates(path):
    """Keep the first entry of each name. Blender's builder (4.5 and 5.0) writes the wheels
    twice when [build] paths is given: it appends them to the paths and adds them again."""
    with zipfile.ZipFile(path) as src:
        infos = src.infolist()
        if len({i.filename for i in infos}) == len(infos):
            return
        tmp = path + ".part"
        seen = set()
        with zipfile.ZipFile(tmp, "w") as dst:
            for info in infos:
                if info.filename not in seen:
                    seen.add(info.filename)
                    dst.writestr(info, src.read(info), compress_type=info.compress_type)
    os.replace(tmp, path)


def build_legacy(out_dir, manifest, root=ROOT):
    """The legacy zip straight from the allow-list (no builder, no wheel)."""
    legacy = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}-legacy.zip")
    tmp = legacy + ".part"
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
        for rel in (MANIFEST, *manifest["build"]["paths"]):
            dst.write(os.path.join(root, rel), f"{manifest['id']}/{rel}")
    os.replace(tmp, legacy)
    return legacy


def build(out_dir, root=ROOT):
    """Paths of the archives built: the extension zip (when its wheels are there) and the legacy zip."""
    with open(os.path.join(root, MANIFEST), "rb") as fh:
        manifest = tomllib.load(fh)
    os.makedirs(out_dir, exist_ok=True)
    built = []
    missing = [w for w in manifest.get("wheels", []) if not os.path.isfile(os.path.join(root, w))]
    if missing:
        print(
            f"package: skipping the extension zip, wheel(s) missing (run scripts/setup.sh): {', '.join(missing)}",
            file=sys.stderr,
        )
    else:
        ext = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}.zip")
        if os.path.exists(ext):
            os.unlink(ext)  # the builder refuses to overwrite
        # -W: the builder's second copy of each wheel (removed below) is not the user's concern
        subprocess.run(
            [
                sys.executable,
                "-W",
                "ignore:Duplicate name",
                blender_ext_tool(),
                "build",
                "--source-dir",
                root,
                "--output-filepath",
                ext,
            ],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        _drop_duplicates(ext)
        built.append(ext)
    built.append(build_legacy(out_dir, manifest, root))
    return built


if __name__ == "__main__":
    for path in build(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "dist")):
        print(path)
