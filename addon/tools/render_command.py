"""``python -m addon render``: original (and edited) spheres rendered by Cycles (SPEC §4, §5).

Needs the ``bpy`` module. OUT ending in .png is display-referred (Standard view, sRGB);
ending in .exr it is linear scene radiance, 32-bit float, so renders compare numerically.
"""

from __future__ import annotations

import os
import time


def _preflight(args, input_error):
    """Checks that need no Blender: the output's name and the guard against the inputs."""
    from ..core.file.safeio import guard_output
    from ..core.file.sources import parse_source

    out = os.fspath(args.out)
    if os.path.splitext(out)[1].lower() not in (".png", ".exr"):
        raise input_error(f"{out}: the output must end in .png (display) or .exr (linear radiance)")
    env = args.env if args.env and (os.sep in args.env or os.path.splitext(args.env)[1]) else None
    # FILE:NAME (a material of a weights set) reads FILE: that is the input to protect.
    guard_output(out, [parse_source(p)[0] for p in (args.file, args.edited, env) if p])
    return out


def run_in_child(args, input_error):
    """Run the render in a child process and wait for it, so that Ctrl-C is honoured at once.

    Blender's render holds the interpreter until it ends (Ctrl-C was swallowed). The parent
    stays responsive: on Ctrl-C it kills the child, removes the child's temporaries (recorded
    in the journal, see core/file/atomic.py) and Blender's own temporary folder, and re-raises."""
    import shutil
    import signal
    import subprocess
    import sys
    import tempfile

    from ..core.file.atomic import sweep_pending

    _preflight(args, input_error)
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    scratch = tempfile.mkdtemp(prefix="brdfm-render-")  # Blender's temporary folder, removed below
    env = dict(
        os.environ,
        BRDF_MOMENTS_RENDER_CHILD="1",
        TMPDIR=scratch,
        TEMP=scratch,
        TMP=scratch,
        PYTHONPATH=os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])),
    )
    child = None
    try:
        child = subprocess.Popen([sys.executable, "-m", "addon", *args.argv], env=env)
        code = child.wait()
        if code < 0:  # killed by a signal (Blender itself crashed): one line, and nothing left
            sweep_pending(only_pid=child.pid)
            raise input_error(
                f"{args.file}: the render stopped unexpectedly (Blender died of signal {-code}); nothing was written"
            )
        return code
    except KeyboardInterrupt:
        if child is not None:
            child.send_signal(signal.SIGKILL) if hasattr(signal, "SIGKILL") else child.kill()
            child.wait()
            sweep_pending(only_pid=child.pid)
        raise
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def run(args, input_error):
    import signal

    from ..core.file.nbrdf import read_table

    if os.environ.get("BRDF_MOMENTS_RENDER_CHILD") == "1":
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
    out = _preflight(args, input_error)
    original = read_table(args.file)
    edited = read_table(args.edited) if args.edited else None
    t0 = time.perf_counter()
    try:
        from ..wheel import import_bpy

        bpy = import_bpy()
    except ImportError as exc:
        raise input_error(str(exc)) from None
    from ..blender import preview

    try:
        env = preview.resolve_environment(args.env)
    except ValueError as exc:
        raise input_error(str(exc)) from None
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    try:
        with preview.quiet_stdout():
            info = preview.build_preview(
                scene,
                original,
                edited,
                path=args.path,
                mode=args.mode,
                env=env,
                size=args.size,
                samples=args.samples,
                lobe_samples=args.lobe_samples,
                bake_samples=args.bake_samples,
            )
        preview.render_still(scene, out, quiet=True)
    except preview.OSLUnavailable as exc:
        raise input_error(f"--path osl: {exc}") from None
    how = f"OSL, {info.mode} mode" if info.path == "osl" else "baked"
    print(
        f"wrote {out} ({how}, {info.layout.width}x{info.layout.height}, environment "
        f"{os.path.basename(info.environment)}, {time.perf_counter() - t0:.1f} s)"
    )
    return 0
