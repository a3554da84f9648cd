"""Per-material state: the source file, the analysis (stored compactly), fits and sliders.

The analysis is kept in the .blend as base64 float32 (about 30 KB per material), so a saved
file reopens with its profiles even when the 35 MB MERL file is gone.
"""

import base64
import math

import bpy
import numpy as np

from .core.moments import CHANNELS, PROFILE_KEYS


def pack_profiles(prof) -> str:
    arr = np.stack([np.stack([prof[ch][k] for k in PROFILE_KEYS]) for ch in CHANNELS]).astype("<f4")
    head = np.concatenate([[len(prof.theta_o)], prof.theta_o, prof.kd]).astype("<f4")
    return base64.b64encode(head.tobytes() + arr.tobytes()).decode("ascii")


def unpack_profiles(text: str):
    from .core.profiles import Profiles

    raw = np.frombuffer(base64.b64decode(text.encode("ascii")), dtype="<f4").astype(float)
    n = int(raw[0])
    theta, kd = raw[1:1 + n], raw[1 + n:4 + n]
    arr = raw[4 + n:].reshape(len(CHANNELS), len(PROFILE_KEYS), n)
    channels = {ch: {k: arr[i, j] for j, k in enumerate(PROFILE_KEYS)} for i, ch in enumerate(CHANNELS)}
    return Profiles(theta, kd, channels)


class BRDFMomentsMaterial(bpy.types.PropertyGroup):
    source_path: bpy.props.StringProperty(name="MERL file", subtype="FILE_PATH")
    analysed: bpy.props.BoolProperty(default=False)
    profiles_data: bpy.props.StringProperty(options={"HIDDEN"})
    kd: bpy.props.FloatVectorProperty(name="kd", size=3, subtype="COLOR", min=0.0, soft_max=1.0)
    fit_alpha_b: bpy.props.FloatProperty(name="α̃b")
    fit_theta0: bpy.props.FloatProperty(name="θ0", subtype="ANGLE")
    fit_theta1: bpy.props.FloatProperty(name="θ1", subtype="ANGLE")
    fit_alpha1: bpy.props.FloatProperty(name="α1")
    fit_m1: bpy.props.FloatProperty(name="m1")
    fit_mu_slope: bpy.props.FloatProperty(name="μ̃")
    fit_sigma2: bpy.props.FloatProperty(name="σ̃²")
    fit_energy_rmse: bpy.props.FloatProperty(name="energy RMSE")
    fit_mean_rmse: bpy.props.FloatProperty(name="mean RMSE")
    fit_variance_rmse: bpy.props.FloatProperty(name="variance RMSE")
    fit_notes: bpy.props.StringProperty(name="notes")
    # Sliders (the edit operators arrive with the editing issue).
    strength: bpy.props.FloatProperty(name="Strength", default=1.0, min=0.0, soft_max=4.0)
    colour: bpy.props.FloatVectorProperty(name="Colour", size=3, subtype="COLOR", default=(1.0, 1.0, 1.0), min=0.0)
    grazing_boost: bpy.props.FloatProperty(name="Grazing boost", default=1.0, min=0.0, soft_max=4.0)
    mu_slope: bpy.props.FloatProperty(name="Mean slope μ̃", default=-0.5, min=-1.0, max=0.0)
    sigma2: bpy.props.FloatProperty(name="Variance σ̃²", default=0.1, min=1e-6, max=math.pi ** 2 / 12)
    lock: bpy.props.BoolProperty(name="Follow correlation", default=False)
    mode: bpy.props.EnumProperty(name="Mode", items=[("warp", "Warp", "keep the measured shape"),
                                                     ("model", "Model", "paper Eq. 7")], default="warp")

    def store_analysis(self, prof, fit):
        self.profiles_data = pack_profiles(prof)
        self.kd = [float(v) for v in prof.kd]
        self.analysed = True
        for key in ("alpha_b", "theta0", "theta1", "alpha1", "m1", "mu_slope", "sigma2"):
            value = fit.get(key)
            setattr(self, f"fit_{key}", float(value) if value is not None and math.isfinite(value) else 0.0)
        for key in ("energy", "mean", "variance"):
            value = fit[key]["rmse"]
            setattr(self, f"fit_{key}_rmse", float(value) if value is not None else 0.0)
        self.fit_notes = "; ".join(fit.get("notes", []))
        # Sliders start at the fitted values (clamped to their ranges).
        if fit.get("mu_slope") is not None:
            self.mu_slope = min(max(fit["mu_slope"], -1.0), 0.0)
        if fit.get("sigma2") is not None:
            self.sigma2 = min(max(fit["sigma2"], 1e-6), math.pi ** 2 / 12)

    def profiles(self):
        return unpack_profiles(self.profiles_data) if self.profiles_data else None


CLASSES = (BRDFMomentsMaterial,)


def attach():
    bpy.types.Material.brdf_moments = bpy.props.PointerProperty(type=BRDFMomentsMaterial)


def detach():
    del bpy.types.Material.brdf_moments
