"""Register -> unregister -> register with work in flight, in any Blender (3.4 under blender -b,
the bpy 4.5 and 5.0 modules under pytest).

Before the unregister: a material loaded and analysed, Build Preview run (baked), then two
things left running at once: a job whose work runs in a forked child (driven the way Blender
drives a modal operator, with a stand-in window manager, since there is no window), the live
preview's real work in its thread (the draft and full synthesis and bake of a slider move) with
its timer. (Plots are drawn in a thread only with a window.) The unregister must end all of them; the
register after it must give a working add-on (Load and Apply run again).

    blender -b -P tests/blender/cycle.py -- --module brdf_moments --sample ggx_glossy --out DIR

writes DIR/cycle.json; ``run(bpy, module, merl, out)`` does the same in-process.
"""

import json
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class _WM:
    def __init__(self):
        self.progress, self.timers, self.handlers, self.windows = [], 0, [], [object()]

    def event_timer_add(self, step, window=None):
        self.timers += 1
        return object()

    def event_timer_remove(self, timer):
        self.timers -= 1

    def progress_begin(self, lo, hi):
        self.progress.append(("begin", lo, hi))

    def progress_update(self, value):
        self.progress.append(value)

    def progress_end(self):
        self.progress.append("end")

    def modal_handler_add(self, op):
        self.handlers.append(op)


class _Workspace:
    def __init__(self):
        self.status = []

    def status_text_set(self, text):
        self.status.append(text)


class _Context:
    def __init__(self):
        self.window_manager, self.workspace, self.window = _WM(), _Workspace(), object()


class _Event:
    type, value = "NONE", "NOTHING"


def _mod(module, name):
    return sys.modules[f"{module}.addon.blender.{name}"]


def run(bpy, module, merl, out):
    import addon_utils

    result = {"blender": bpy.app.version_string}
    mat = bpy.data.materials.new("cycle")
    mat.use_fake_user = True
    result["load"] = sorted(bpy.ops.brdf_moments.load_merl(filepath=merl, material=mat.name))
    result["preview"] = sorted(bpy.ops.brdf_moments.build_preview(material=mat.name, path="BAKED", size=32, samples=4))

    jobs, live, images, lifecycle = (_mod(module, n) for n in ("jobs", "live", "images", "lifecycle"))

    # 1. A job in flight, its work in a forked child (where the platform forks).
    class Job(jobs.BackgroundJob):
        job_label = "Cycle"

        def __init__(self):
            self.reports = []

        @staticmethod
        def has_window(context):
            return True

        def report(self, level, text):
            self.reports.append(text)

        def start(self, context):
            def work(report_progress):
                for k in range(600):
                    report_progress(k, 600)
                    time.sleep(0.1)
                return "never"

            return work

        def finish(self, context, result):
            raise AssertionError("a job ended by unregister must not finish")

    ctx = _Context()
    op = Job()
    op.invoke(ctx, _Event())
    # 2. The live preview's own work for a slider move, in its thread, with its timer.
    state = mat.brdf_moments
    state.sigma2 = state.fit_sigma2 * 1.3
    job = live._job(mat)
    assert job is not None, "no live preview after Build Preview"
    gen = live._GEN.get(mat.name, 0) + 1
    live._GEN[mat.name] = gen
    posted = []
    live._start(lambda: live._work(job, stale=lambda: live._GEN.get(mat.name) != gen, post=lambda *a: posted.append(a)))
    time.sleep(0.5)  # everything under way
    result["before"] = {
        "jobs": jobs.running(),
        "threads": sorted(t.name for t in lifecycle.threads()),
        "timers": len(lifecycle.timers()),
        "child_alive": bool(op._proc is not None and op._proc.is_alive()),
    }
    proc = op._proc
    # the live work may already have posted its draft (0.3-0.5 s quiet since the synthesis reads
    # only the horizon band): what counts is that nothing is posted once unregister has begun
    posted_before = len(posted)
    t0 = time.monotonic()
    addon_utils.disable(module, default_set=False)
    result["unregister_seconds"] = round(time.monotonic() - t0, 2)
    registration = sys.modules[f"{module}.addon.blender.registration"]
    result["after"] = {
        "shutdown": dict(registration.LAST_SHUTDOWN),
        "property": hasattr(bpy.types.Material, "brdf_moments"),
        "jobs": jobs.running(),
        "history": jobs.HISTORY[-1]["outcome"] if jobs.HISTORY else None,
        "threads": sorted(t.name for t in lifecycle.threads()),
        "timers": len(lifecycle.timers()),
        "live_timer": bpy.app.timers.is_registered(live._apply_posted),
        "draw_timer": bpy.app.timers.is_registered(images._place_drawn),
        "child_alive": bool(proc is not None and proc.is_alive()),
        "child_exitcode": None if proc is None else proc.exitcode,
        "wm_timers": ctx.window_manager.timers,
        "progress_end": ctx.window_manager.progress[-1:] == ["end"],
        "reports": op.reports,
        "posted_after": len(posted) - posted_before,
    }
    addon_utils.enable(module, default_set=False)
    mat = bpy.data.materials["cycle"]
    result["again"] = {
        "property": hasattr(bpy.types.Material, "brdf_moments"),
        "load": sorted(bpy.ops.brdf_moments.load_merl(filepath=merl, material=mat.name)),
    }
    mat.brdf_moments.sigma2 = mat.brdf_moments.fit_sigma2 * 1.2
    result["again"]["apply"] = sorted(bpy.ops.brdf_moments.apply_edit(material=mat.name))
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "cycle.json"), "w") as fh:
        json.dump(result, fh, indent=1, default=str)
    return result


if __name__ == "__main__":
    import argparse

    import bpy

    sys.path.insert(0, ROOT)
    from addon.script_args import script_args

    p = argparse.ArgumentParser()
    p.add_argument("--module", default="brdf_moments")
    p.add_argument("--sample", default="ggx_glossy")
    p.add_argument("--out", required=True)
    a, _ = p.parse_known_args(script_args())
    import samples

    run(bpy, a.module, samples.sample_path(a.sample), a.out)
    print("cycle: done", flush=True)
