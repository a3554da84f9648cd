"""Per-material state: the source file, the analysis (stored compactly), fits and sliders.

The analysis is kept in the .blend as base64 float32 (about 30 KB per material), so a saved
file reopens with its profiles even when the 35 MB MERL file is gone.
"""

import base64
import math

import bpy
import numpy as np

from ..core.fits.curves import LAMBERT_VARIANCE, MIN_SIGMA2
from ..core.limits import MAX_ELEVATIONS, MAX_RENDER_SIZE, MU_SLOPE_RANGE, RANGES
from ..core.profiles.moments import CHANNELS, PROFILE_KEYS
from . import lifecycle
from .images import draw_later

MU_MIN, MU_MAX = MU_SLOPE_RANGE  # the declared ranges (core/limits.py), shared with the command line
# The slider reaches below the model's floor (MIN_SIGMA2): the edit clamps it and says so.
SIGMA2_MIN, SIGMA2_MAX = RANGES["sigma2"].low, RANGES["sigma2"].high


# The sliders by the names the panel shows (the one-line error of a value out of range).
SLIDER_LABELS = {
    "strength": "Strength",
    "colour": "Colour",
    "grazing_boost": "Grazing boost",
    "mu_slope": "Mean slope μ̃",
    "sigma2": "Variance σ̃²",
    "correlation_a": "Correlation a",
}


def clamp_mu(v):
    return min(max(float(v), MU_MIN), MU_MAX)


def clamp_sigma2(v):
    return min(max(float(v), SIGMA2_MIN), SIGMA2_MAX)


def pack_profiles(prof) -> str:
    """Profiles as base64 of float64 (about 60 kB for 90 views): the stored analysis is the one
    the engine made, bit for bit, so an Apply or a live preview from it edits exactly what the
    command line edits. (Before 2026-12-02 they were stored as float32: still read.)"""
    arr = np.stack([np.stack([prof[ch][k] for k in PROFILE_KEYS]) for ch in CHANNELS]).astype("<f8")
    head = np.concatenate([[len(prof.theta_o)], prof.theta_o, prof.kd]).astype("<f8")
    return base64.b64encode(head.tobytes() + arr.tobytes()).decode("ascii")


def _stored_floats(data: bytes):
    """The stored numbers: float64, or float32 from older files (whichever length fits)."""
    for dtype in ("<f8", "<f4"):
        size = np.dtype(dtype).itemsize
        if len(data) % size:
            continue
        raw = np.frombuffer(data, dtype=dtype).astype(float)
        n = int(raw[0]) if len(raw) and np.isfinite(raw[0]) and 1 <= raw[0] <= MAX_ELEVATIONS else -1
        if n >= 1 and len(raw) == 4 + n + len(CHANNELS) * len(PROFILE_KEYS) * n:
            return n, raw
    raise ValueError("the stored analysis is damaged (wrong length); analyse the material again")


def unpack_profiles(text: str):
    from ..core.profiles.compute import Profiles

    # Stored in the .blend, so it may be damaged or edited: checked before anything uses it.
    try:
        data = base64.b64decode(text.encode("ascii"), validate=True)
    except (ValueError, UnicodeEncodeError):
        raise ValueError("the stored analysis is damaged (not base64 float data); analyse the material again") from None
    n, raw = _stored_floats(data)
    theta, kd = raw[1 : 1 + n], raw[1 + n : 4 + n]
    arr = raw[4 + n :].reshape(len(CHANNELS), len(PROFILE_KEYS), n)
    if not (np.isfinite(theta).all() and np.isfinite(kd).all()) or np.isinf(arr).any():
        raise ValueError("the stored analysis is damaged (inf or NaN where numbers belong); analyse the material again")
    channels = {ch: {k: arr[i, j] for j, k in enumerate(PROFILE_KEYS)} for i, ch in enumerate(CHANNELS)}
    return Profiles(theta, kd, channels)


class BRDFMomentsMaterial(bpy.types.PropertyGroup):
    # A MERL file, or FILE:NAME for a material of a Neural-BRDF weights file (see Load).
    source_path: bpy.props.StringProperty(name="MERL file", subtype="FILE_PATH")
    analysed: bpy.props.BoolProperty(default=False)
    floor: bpy.props.EnumProperty(
        name="Diffuse floor",
        default="min",
        update=lambda self, ctx: _floor_changed(self),
        description="how kd is taken from the 45° slice; changing it asks for a new analysis",
        items=[
            ("min", "Minimum", "the minimum over the 45° slice (the paper, Sec. 2.2)"),
            (
                "robust",
                "Robust",
                "the 5th percentile by area of the slice's cells within 70° of the normal: "
                "one low grazing cell of a measured table cannot set it",
            ),
        ],
    )
    profiles_data: bpy.props.StringProperty(options={"HIDDEN"})
    kd: bpy.props.FloatVectorProperty(name="kd", size=3, min=0.0, soft_max=1.0, precision=4)
    kd_albedo: bpy.props.FloatVectorProperty(
        name="Diffuse albedo",
        size=3,
        subtype="COLOR",
        description="π·kd, the diffuse part's albedo (read-only)",
        get=lambda self: [min(max(math.pi * v, 0.0), 1.0) for v in self.kd],
    )
    fit_alpha_b: bpy.props.FloatProperty(name="α̃b")
    fit_theta0: bpy.props.FloatProperty(name="θ0", subtype="ANGLE")
    fit_theta1: bpy.props.FloatProperty(name="θ1", subtype="ANGLE")
    fit_alpha1: bpy.props.FloatProperty(name="α1")
    fit_m1: bpy.props.FloatProperty(name="m1")
    # Per-channel energy fits: alpha_b (r, g, b), alpha1 (r, g, b), m1 (r, g, b).
    fit_channels: bpy.props.FloatVectorProperty(size=9, options={"HIDDEN"})
    fit_mu_slope: bpy.props.FloatProperty(name="μ̃")
    fit_sigma2: bpy.props.FloatProperty(name="σ̃²")
    fit_energy_rmse: bpy.props.FloatProperty(name="energy RMSE")
    fit_mean_rmse: bpy.props.FloatProperty(name="mean RMSE")
    fit_variance_rmse: bpy.props.FloatProperty(name="variance RMSE")
    fit_notes: bpy.props.StringProperty(name="notes")
    # The engine's whole fit (JSON, float64): what Apply and the live preview edit from. The
    # float properties above are for display (and older files, which have no fit_data).
    fit_data: bpy.props.StringProperty(options={"HIDDEN"})
    # The analysed file's size and modification time (JSON): Apply edits from the stored analysis,
    # so it refuses a file that changed since.
    source_stamp: bpy.props.StringProperty(options={"HIDDEN"})
    # Sliders.
    strength: bpy.props.FloatProperty(
        name="Strength",
        default=1.0,
        **RANGES["strength"].prop(),
        soft_max=4.0,
        update=lambda self, ctx: _slider_moved(self),
    )
    colour: bpy.props.FloatVectorProperty(
        name="Colour",
        size=3,
        subtype="COLOR",
        default=(1.0, 1.0, 1.0),
        **RANGES["colour"].prop(),
        soft_max=1.0,
        update=lambda self, ctx: _slider_moved(self),
    )
    grazing_boost: bpy.props.FloatProperty(
        name="Grazing boost",
        default=1.0,
        **RANGES["grazing_boost"].prop(),
        soft_max=4.0,
        update=lambda self, ctx: _slider_moved(self),
    )
    # Hard ranges wide enough for every fitted value (measured mu goes below -1); the soft
    # range is what a drag covers.
    mu_slope: bpy.props.FloatProperty(
        name="Mean slope μ̃",
        default=-0.5,
        min=MU_MIN,
        max=MU_MAX,
        soft_min=-1.5,
        soft_max=0.0,
        precision=3,
        update=lambda self, ctx: _slider_moved(self),
    )
    sigma2: bpy.props.FloatProperty(
        name="Variance σ̃²",
        default=0.1,
        min=SIGMA2_MIN,
        max=SIGMA2_MAX,
        precision=5,
        update=lambda self, ctx: _slider_moved(self),
    )
    lock: bpy.props.BoolProperty(
        name="Follow correlation",
        default=False,
        update=lambda self, ctx: _slider_moved(self),
        description="move the variance with the mean slope along the correlation quadratic",
    )
    correlation_a: bpy.props.FloatProperty(
        name="Correlation a",
        default=0.0,
        **RANGES["correlation_a"].prop(),
        update=lambda self, ctx: _slider_moved(self) if self.lock else region_image(self.id_data, later=True),
        description="the quadratic's a in σ̃² = a μ̃² + (a + π²/12) μ̃ + π²/12 (fit a set with 'python -m addon analyze', then Load Set)",
    )
    mode: bpy.props.EnumProperty(
        name="Mode",
        items=[("warp", "Warp", "keep the measured shape"), ("model", "Model", "paper Eq. 7")],
        default="warp",
        update=lambda self, ctx: _slider_moved(self),
    )
    # The reachable region per mode (JSON of core.edit.reach.ReachableRegion), from the analysis.
    region_data: bpy.props.StringProperty(options={"HIDDEN"})
    # What Apply will deliver for the sliders as they stand (``refresh_announcement``), JSON.
    announced_json: bpy.props.StringProperty(options={"HIDDEN"})
    # An analysed set shown on the region plot (Load Set): [[name, mu_slope, sigma2], ...] as
    # compact JSON, and the fits.json it came from (for the panel; never written to).
    set_data: bpy.props.StringProperty(options={"HIDDEN"})
    set_path: bpy.props.StringProperty(name="Set", subtype="FILE_PATH", options={"HIDDEN"})
    # The last re-synthesis (Apply).
    edited_path: bpy.props.StringProperty(name="Edited table", subtype="FILE_PATH")
    edited_profiles_data: bpy.props.StringProperty(options={"HIDDEN"})
    achieved_mu_slope: bpy.props.FloatProperty(name="reached μ̃")
    achieved_sigma2: bpy.props.FloatProperty(name="reached σ̃²")
    max_albedo: bpy.props.FloatVectorProperty(name="Largest albedo", size=3, min=0.0)
    edit_warnings: bpy.props.StringProperty(name="Warnings")
    # The last edit's per-view figures (JSON of core.edit.fidelity.Fidelity.summary()).
    edit_fidelity: bpy.props.StringProperty(options={"HIDDEN"})
    edit_report: bpy.props.StringProperty(options={"HIDDEN"})  # the last Apply's per-view promise (JSON)
    plot_caption: bpy.props.StringProperty(options={"HIDDEN"})  # the plot's y ranges, one chart a line
    preview_material: bpy.props.StringProperty(options={"HIDDEN"})  # the edited sphere's material
    preview_path: bpy.props.EnumProperty(
        name="Preview path",
        default="AUTO",
        items=[
            ("AUTO", "Auto", "the baked path (the accurate one); OSL on request"),
            ("OSL", "OSL", "Cycles OSL shader (noisier at the same time)"),
            ("BAKED", "Baked", "numpy radiance per texel through an Emission shader (any engine)"),
        ],
    )
    preview_mode: bpy.props.EnumProperty(
        name="Preview",
        default="TABULATED",
        items=[
            ("TABULATED", "Tabulated", "the edited table itself (the material)"),
            (
                "MODEL",
                "Sketch (moment model)",
                "a statistical summary of the fits (paper Eq. 7), not the material: drags update it live",
            ),
        ],
    )
    artist_shader: bpy.props.EnumProperty(
        name="Shader",
        default="AUTO",
        items=[
            (
                "AUTO",
                "Auto",
                "OSL tabulated where the scene renders with Cycles OSL, else the fitted lobes (or the Principled "
                "approximation where its BRDF error is lower and its albedo within 10 %)",
            ),
            (
                "LOBES",
                "Lobes (approx.)",
                "GGX lobes (stretched across the plane of incidence where Cycles renders) and a diffuse lobe, "
                "their colours following the view angle, fitted to the edited table: any engine",
            ),
            ("PRINCIPLED", "Principled (approx.)", "a Principled BSDF fitted to the edited table: any engine"),
            ("OSL", "OSL tabulated", "the edited table itself, read by an OSL shader (Cycles with OSL)"),
            ("NONE", "Leave material", "Apply does not touch the material's nodes"),
        ],
    )
    texture_storage: bpy.props.EnumProperty(
        name="Table texture",
        default="PACK",
        items=[
            ("PACK", "Packed in .blend", "the OSL table texture or the lobes' lookup is packed into the .blend"),
            (
                "BESIDE",
                "Next to .blend",
                "the OSL table texture or the lobes' lookup is written next to the saved .blend (//brdf_moments/)",
            ),
        ],
    )
    principled_data: bpy.props.StringProperty(options={"HIDDEN"})  # the last Principled fit (JSON)
    lobes_data: bpy.props.StringProperty(options={"HIDDEN"})  # the last lobe fit (JSON)
    artist_shader_used: bpy.props.StringProperty(options={"HIDDEN"})  # "lobes" / "principled" / "osl" / ""
    preview_env: bpy.props.StringProperty(
        name="Environment",
        default="",
        description="a bundled HDRI name (empty: the default studio light) or an .exr/.hdr file of your own",
    )
    preview_size: bpy.props.IntProperty(name="Size", default=256, min=16, max=MAX_RENDER_SIZE, subtype="PIXEL")
    scale_to_one: bpy.props.BoolProperty(
        name="Scale albedo to 1",
        default=False,
        description="scale the edited material down so that it reflects no more light than it receives",
    )

    def store_analysis(self, prof, fit, keep_sliders=False):
        self.profiles_data = pack_profiles(prof)
        self.kd = [float(v) for v in prof.kd]
        self.analysed = True
        for key in ("alpha_b", "theta0", "theta1", "alpha1", "m1", "mu_slope", "sigma2"):
            value = fit.get(key)
            setattr(self, f"fit_{key}", float(value) if value is not None and math.isfinite(value) else 0.0)
        for key in ("energy", "mean", "variance"):
            value = fit[key]["rmse"]
            setattr(self, f"fit_{key}_rmse", float(value) if value is not None else 0.0)
        chans = fit.get("channels") or {}
        self.fit_channels = [float(chans.get(c, {}).get(k) or 0.0) for k in ("alpha_b", "alpha1", "m1") for c in "rgb"]
        self.fit_notes = "; ".join(fit.get("notes", []))
        import json

        self.fit_data = json.dumps(fit, default=lambda v: v.item() if hasattr(v, "item") else str(v))
        # Sliders start at the fitted values (their ranges hold every fitted value).
        if keep_sliders:
            return
        if fit.get("mu_slope") is not None:
            self.mu_slope = clamp_mu(fit["mu_slope"])
        if fit.get("sigma2") is not None:
            self.sigma2 = clamp_sigma2(fit["sigma2"])

    def lobes_fit(self):
        """The lobe mixture fitted to the last edited table, or None (also when unreadable)."""
        import json

        from ..core.material.lobes import LobeFit

        if not self.lobes_data:
            return None
        try:
            return LobeFit.from_dict(json.loads(self.lobes_data))
        except (ValueError, KeyError, TypeError):
            return None

    def principled_fit(self):
        """The Principled BSDF fitted to the last edited table, or None."""
        import json

        from ..core.material.principled import PrincipledFit

        if not self.principled_data:
            return None
        d = json.loads(self.principled_data)
        return PrincipledFit(
            tuple(d["base_color"]), d["metallic"], d["roughness"], d["specular"], d["error"], d["albedo_error"]
        )

    def principled_bound(self):
        """``node_bound`` of the table the last Principled fit was fitted to, or None."""
        import json

        if not self.principled_data:
            return None
        b = json.loads(self.principled_data).get("bound")
        return None if b is None else float(b)

    def profiles(self):
        return unpack_profiles(self.profiles_data) if self.profiles_data else None

    def edited_profiles(self):
        return unpack_profiles(self.edited_profiles_data) if self.edited_profiles_data else None

    def fidelity(self):
        """The last edit's per-view figures as a dict (None if none, or the stored copy is damaged)."""
        from ..core.edit.fidelity import summary_from_json

        return summary_from_json(self.edit_fidelity)

    def fit(self) -> dict:
        """The stored fit as the engine's dict: the one the analysis made (``fit_data``), else
        (older files) rebuilt from the float properties, enough for editing and plotting."""
        import json

        values = [
            self.fit_alpha_b,
            self.fit_theta0,
            self.fit_theta1,
            self.fit_alpha1,
            self.fit_m1,
            self.fit_mu_slope,
            self.fit_sigma2,
            *self.fit_channels,
            *self.kd,
        ]
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"{self.id_data.name}: the stored fits hold inf or NaN; analyse the material again")
        if self.fit_data:
            try:
                d = json.loads(self.fit_data)
            except ValueError:
                d = None
            keys = ("alpha_b", "theta0", "theta1", "alpha1", "m1", "mu_slope", "sigma2")
            if isinstance(d, dict) and all(
                d.get(k) is None or (isinstance(d.get(k), (int, float)) and math.isfinite(d[k])) for k in keys
            ):
                return d
            raise ValueError(f"{self.id_data.name}: the stored fit is damaged; analyse the material again")
        return {
            "alpha_b": self.fit_alpha_b,
            "theta0": self.fit_theta0,
            "theta1": self.fit_theta1,
            "alpha1": self.fit_alpha1,
            "m1": self.fit_m1,
            "mu_slope": self.fit_mu_slope,
            "sigma2": self.fit_sigma2,
            "channels": {
                c: {"alpha_b": self.fit_channels[i], "alpha1": self.fit_channels[3 + i], "m1": self.fit_channels[6 + i]}
                for i, c in enumerate("rgb")
            },
        }

    def model_params(self, edited=False):
        """The moment model (paper Eq. 7) of the fits, or of the fits moved by the sliders."""
        from ..core.fits.curves import correlation_curve
        from ..core.preview import MomentParams

        params = MomentParams.from_fit(self.fit(), tuple(self.kd))
        if not edited:
            return params
        s2 = float(correlation_curve(self.mu_slope, self.correlation_a)) if self.lock else self.sigma2
        return params.edited(
            self.strength,
            tuple(self.colour),
            self.grazing_boost,
            self.mu_slope,
            min(max(s2, MIN_SIGMA2), LAMBERT_VARIANCE),
        )

    def reset_sliders(self):
        self.strength, self.colour, self.grazing_boost = 1.0, (1.0, 1.0, 1.0), 1.0
        self.mu_slope = clamp_mu(self.fit_mu_slope)
        self.sigma2 = clamp_sigma2(self.fit_sigma2)
        self.lock = False
        self.refresh_announcement()

    def region(self):
        """The reachable region for the current mode, or None (not analysed, no lobe, damaged)."""
        import json

        from ..core.edit.reach import ReachableRegion

        try:
            data = json.loads(self.region_data) if self.region_data else {}
            return ReachableRegion.from_json(data[self.mode]) if self.mode in data else None
        except (ValueError, TypeError, KeyError):
            return None

    def set_points(self):
        """The loaded set's [(name, mu_slope, sigma2)], or [] (none loaded, or damaged in the
        .blend: a damaged set is not drawn, never a traceback in the panel)."""
        import json

        if not self.set_data:
            return []
        try:
            rows = json.loads(self.set_data)
            out = [(str(n), float(m), float(s)) for n, m, s in rows]
        except (ValueError, TypeError):
            return []
        return [p for p in out if math.isfinite(p[1]) and math.isfinite(p[2])]

    def requested_point(self):
        """((mu, sigma2) the sliders ask for, (mu, sigma2) Apply will use) or None: the region's
        clamp, as ``edit`` does it, so the panel says so before Apply."""
        from ..core.edit.targets import resolve_targets

        region = self.region()
        if region is None:
            return None
        try:
            targets = self.slider_targets()
        except ValueError:
            return None  # Apply will say which slider is out of range
        if targets.is_energy_only() or targets.is_identity():
            return None
        from ..core.edit.solve import is_roughness_edit, roughness_point

        try:
            if is_roughness_edit(targets) and region.curve:
                asked, used, _ = roughness_point(targets, self.fit(), region)  # what Apply does
                return asked, used
            mu, s2, _ = resolve_targets(targets, self.fit())
        except ValueError:
            return None
        mu_c, s2_c, _ = region.clamp(mu, s2)
        return (mu, s2), (mu_c, s2_c)

    def announcement(self):
        """The engine's ``Announcement`` for the sliders as they stand, or None (not analysed,
        no lobe, damaged stored analysis): the same call Apply's edit makes first."""
        return _announce(*self._announce_inputs())

    def _announce_inputs(self):
        """What the announcement reads, taken from the material (cheap: on the main thread)."""
        try:
            return self.profiles_data if self.analysed else "", self.fit(), self.slider_targets(), self.region()
        except (ValueError, TypeError, KeyError):
            return "", None, None, None

    def refresh_announcement(self):
        """Store what Apply will deliver (the panel draws it beside the sliders). In a window it
        is worked out in a thread (its first call per analysis inverts every view's lobe: many
        small numpy calls, each waiting for the GIL while the live preview runs), then written
        by a timer if no newer slider move asked again."""
        inputs = self._announce_inputs()
        if bpy.app.background:
            self.announced_json = _announcement_json(_announce(*inputs))
            return
        from .lifecycle import register_timer

        name = self.id_data.name
        _ANNOUNCED["gen"] = gen = _ANNOUNCED.get("gen", 0) + 1
        done = []

        def work():  # numpy only: a thread must not call into Blender (not even to add a timer)
            try:
                done.append(_announcement_json(_announce(*inputs)))
            except Exception as exc:  # noqa: BLE001 - the last announcement stays
                print(f"BRDF Moments: announcing: {type(exc).__name__}: {exc}")
                done.append(None)

        def place():  # on the main thread, registered from it
            if _ANNOUNCED.get("gen") != gen:
                return None  # a newer slider move asked again
            if not done:
                return 0.05
            mat = bpy.data.materials.get(name)
            if mat is not None and done[0] is not None:
                mat.brdf_moments.announced_json = done[0]
            return None

        _ANNOUNCER.submit(work)
        register_timer(place, first_interval=0.05)

    def slider_targets(self):
        """The sliders as engine targets; a slider still at its fitted value stays exact.
        ValueError (one line naming the slider) for a value outside its declared range (a file
        saved by another version, or a script that bypassed the property)."""
        from ..core.edit import EditTargets
        from ..core.limits import check_targets

        at_fit_mu = abs(self.mu_slope - clamp_mu(self.fit_mu_slope)) < 1e-6
        at_fit_s2 = abs(self.sigma2 - clamp_sigma2(self.fit_sigma2)) <= 1e-7 * max(self.fit_sigma2, 1e-6)
        return check_targets(
            EditTargets(
                strength=self.strength,
                colour=tuple(self.colour),
                grazing_boost=self.grazing_boost,
                mu_slope=None if at_fit_mu and not self.lock else self.mu_slope,
                sigma2=None if at_fit_s2 or self.lock else self.sigma2,
                mode=self.mode,
                lock=self.lock,
                correlation_a=self.correlation_a if self.lock else None,
            ),
            labels=SLIDER_LABELS,
        )


_ANNOUNCED: dict = {}  # the latest announcement asked for (a newer slider move wins)
_ANNOUNCER = lifecycle.LatestWorker("brdf_moments: announce")  # one thread serves every slider move


@lifecycle.on_file_load
def _drop_announcement():
    """Another file is opened: the announcement being worked out is for this one's material."""
    _ANNOUNCED["gen"] = _ANNOUNCED.get("gen", 0) + 1


def _announce(raw, fit, targets, region):
    """``solve.announce`` from stored inputs, or None when there is nothing to announce."""
    from ..core.edit.solve import announce

    prof = unpack_profiles(raw) if raw else None
    if prof is None or fit is None or targets is None:
        return None
    try:
        return announce(prof, fit, targets, region)
    except (ValueError, TypeError, KeyError):
        return None


def _announcement_json(plan) -> str:
    import json

    if plan is None or None in plan.announced:
        return ""
    return json.dumps(
        {
            "mu_slope": plan.announced[0],
            "sigma2": plan.announced[1],
            "out_of_reach": plan.out_of_reach,
            "clamped": plan.clamped,
            "nothing_to_do": plan.nothing_to_do,
        }
    )


def _floor_changed(state):
    # The stored profiles, fits and edits were made with the other floor: analyse again.
    state.analysed = False


def _slider_moved(state):
    """A slider moved: the region plot shows the new point; the panel's preview image follows
    (a draft synthesis and a quick bake, in a thread: ``live``); an OSL sketch preview scene
    only gets new node inputs."""
    if not state.analysed:
        return
    state.refresh_announcement()
    region_image(state.id_data, later=True)
    if state.preview_mode == "TABULATED":
        from . import live

        live.slider_moved(state.id_data)
    if not state.preview_material:
        return
    mat = bpy.data.materials.get(state.preview_material)
    if mat is None or mat.get("brdfm_path") != "osl" or mat.get("brdfm_mode") != "model":
        return
    from .preview import update_model

    try:
        update_model(mat, state.model_params(edited=True))
    except ValueError:
        pass  # the preview was rebuilt as another kind since: nothing to update


PLOT_SIZE = (900, 780)


def plot_image(mat, prof=None, fit=None, edited=None, width=PLOT_SIZE[0], height=PLOT_SIZE[1], later=False):
    """The panel's profile plot for ``mat``: an image named after the material, kept in the
    .blend (fake user; redrawn from the stored profiles when a file is opened). ``later``: in
    a window, drawn off the main thread (``draw_later``) and None returned."""
    from .plot_image import profile_plot

    state = mat.brdf_moments
    prof = prof or state.profiles()
    if prof is None:
        return None
    fit = fit or state.fit()
    edited = edited if edited is not None else state.edited_profiles()
    name = mat.name

    def caption(charts):
        m = bpy.data.materials.get(name)
        if m is not None:
            m.brdf_moments.plot_caption = "\n".join(f"{n}: {lo:.3g} to {hi:.3g}" for n, lo, hi in charts)

    def draw():
        return profile_plot(prof, fit, edited, width, height)

    return draw_later(f"BRDF Moments plot: {name}", draw, caption, now=not later)


REGION_PLOT_SIZE = (600, 420)


def region_image_name(mat):
    return f"BRDF Moments region: {mat.name}"


def region_image(mat, later=False):
    """The reachable-region plot for ``mat`` (kept in the .blend), or None without a region.
    Redrawn when a slider moves (``later``: off the main thread in a window): it shows where
    the sliders are."""
    from .plot_image import region_plot

    state = mat.brdf_moments
    region = state.region()
    if region is None:
        return None
    point = state.requested_point()
    slider, used = point if point else ((state.mu_slope, state.sigma2), None)
    corr = state.correlation_a
    points = [(m, s) for _, m, s in state.set_points()] or None
    prof, fit, targets = state.profiles(), state.fit(), state.slider_targets()

    def draw():
        return region_plot(
            region,
            slider,
            used,
            correlation_a=corr,
            width=REGION_PLOT_SIZE[0],
            height=REGION_PLOT_SIZE[1],
            set_points=points,
            horizon=horizon_curve(prof, fit, targets, region, used or slider),
        )

    return draw_later(region_image_name(mat), draw, now=not later)


def horizon_curve(prof, fit, targets, region, point):
    """The material's horizon curve at the sliders' mean slope: what the table re-fits to for each
    variance request of the region's grid, then the sliders' own point (SPEC §3); None without
    an analysis."""
    import dataclasses

    from ..core.edit.targets import announced, view_targets

    if prof is None or fit is None or fit.get("sigma2") is None:
        return None
    if region is not None and region.curve:
        # Warp mode: the material's curve under roughness edits (SPEC §3), then the point the
        # sliders' variance lands on along it (or the tilted point off it).
        c = region.curve
        mus = [np.nan if v is None else v for v in c["mu"]]
        s2s = [np.nan if v is None else v for v in c["sigma2"]]
        order = np.argsort(np.nan_to_num(np.array(s2s, float), nan=np.inf))
        mu_pt = point[0] if targets.mu_slope is not None else region.curve_mu(point[1])
        return (
            np.append(np.array(mus, float)[order], np.nan if mu_pt is None else mu_pt),
            np.append(np.array(s2s, float)[order], point[1]),
        )
    mus, s2s = [], []
    t = dataclasses.replace(targets, lock=False)
    for s2 in list(region.sigma2) + [point[1]]:
        mu, var = announced(view_targets(prof, fit, t, point[0], float(s2)))
        mus.append(np.nan if mu is None else mu)
        s2s.append(np.nan if var is None else var)
    return np.array(mus), np.array(s2s)


CLASSES = (BRDFMomentsMaterial,)


def attach():
    bpy.types.Material.brdf_moments = bpy.props.PointerProperty(type=BRDFMomentsMaterial)


def detach():
    del bpy.types.Material.brdf_moments
