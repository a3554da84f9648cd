"""Directions, the Rusinkiewicz half/difference angles and the paper's view-centred map.

Local frame: z is the normal. Views lie in the xz-plane (the BRDF is isotropic).
"""

from __future__ import annotations

import numpy as np

HALF_PI = 0.5 * np.pi


def view_centred(theta, phi):
    """Paper Eq. 4: m(theta, phi) = (sin t cos p, sin p, cos t cos p), shape (..., 3)."""
    theta = np.asarray(theta, dtype=float)
    phi = np.asarray(phi, dtype=float)
    cp = np.cos(phi)
    return np.stack(np.broadcast_arrays(np.sin(theta) * cp, np.sin(phi), np.cos(theta) * cp), axis=-1)


def view_centred_angles(w):
    """Inverse of ``view_centred`` for unit vectors with z >= 0."""
    w = np.asarray(w, dtype=float)
    phi = np.arcsin(np.clip(w[..., 1], -1.0, 1.0))
    theta = np.arctan2(w[..., 0], w[..., 2])
    return theta, phi


def _rot_z(v, a):
    c, s = np.cos(a), np.sin(a)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack((c * x - s * y, s * x + c * y, np.broadcast_to(z, np.broadcast(x, c).shape)), axis=-1)


def _rot_y(v, a):
    c, s = np.cos(a), np.sin(a)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack((c * x + s * z, np.broadcast_to(y, np.broadcast(x, c).shape), -s * x + c * z), axis=-1)


def half_diff_from_directions(wi, wo):
    """(theta_h, theta_d, phi_d) of a pair of unit vectors (Rusinkiewicz 1998)."""
    wi = np.asarray(wi, dtype=float)
    wo = np.asarray(wo, dtype=float)
    h = wi + wo
    norm = np.linalg.norm(h, axis=-1, keepdims=True)
    h = h / np.where(norm > 0.0, norm, 1.0)
    theta_h = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    d = _rot_y(_rot_z(wi, -phi_h), -theta_h)
    theta_d = np.arccos(np.clip(d[..., 2], -1.0, 1.0))
    phi_d = np.arctan2(d[..., 1], d[..., 0])
    return theta_h, theta_d, phi_d


def directions_from_half_diff(theta_h, theta_d, phi_d, phi_h=0.0):
    """Inverse map: (wi, wo) for Rusinkiewicz angles."""
    theta_d = np.asarray(theta_d, dtype=float)
    phi_d = np.asarray(phi_d, dtype=float)
    st = np.sin(theta_d)
    d = np.stack((st * np.cos(phi_d), st * np.sin(phi_d), np.cos(theta_d)), axis=-1)
    wi = _rot_z(_rot_y(d, theta_h), phi_h)
    h = _rot_z(_rot_y(np.array([0.0, 0.0, 1.0]), np.asarray(theta_h, float)), phi_h)
    wo = 2.0 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo
