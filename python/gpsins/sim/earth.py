"""The simulator's own Earth model (NumPy), deliberately not the core's.

Gravity here is J2 gravitation plus the centrifugal term, not the Somigliana
normal gravity the filter uses: the two differ by a few 1e-5 m/s^2, about what
a real Earth differs from either, so the filter meets a realistic model
mismatch and a shared mistake cannot hide.
"""

from __future__ import annotations

import numpy as np

A = 6378137.0
F = 1.0 / 298.257223563
E2 = F * (2.0 - F)
GM = 3.986004418e14
J2 = 1.082626683e-3
OMEGA_E = 7.292115e-5
OMEGA_VEC = np.array([0.0, 0.0, OMEGA_E])


def radii(lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Meridian (M) and prime-vertical (N) radii of curvature."""
    s2 = np.sin(lat) ** 2
    w = np.sqrt(1.0 - E2 * s2)
    return A * (1.0 - E2) / w ** 3, A / w


def geodetic_to_ecef(lat, lon, h) -> np.ndarray:
    _, n = radii(lat)
    cl = np.cos(lat)
    return np.stack([(n + h) * cl * np.cos(lon), (n + h) * cl * np.sin(lon), (n * (1.0 - E2) + h) * np.sin(lat)],
                    axis=-1)


def ecef_to_geodetic(r: np.ndarray) -> tuple[float, float, float]:
    """Latitude, longitude (rad) and height of one ECEF point (fixed-point iteration)."""
    x, y, z = r
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - E2))
    for _ in range(8):
        _, n = radii(lat)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - E2 * n / (n + h)))
    _, n = radii(lat)
    return float(lat), float(lon), float(p / np.cos(lat) - n)


def ecef_to_ned_matrix(lat, lon) -> np.ndarray:
    """C_en (..., 3, 3): columns are the north, east and down unit vectors in ECEF."""
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(sl)
    north = np.stack([-sl * co, -sl * so, cl], axis=-1)
    east = np.stack([-so, co, z], axis=-1)
    down = np.stack([-cl * co, -cl * so, -sl], axis=-1)
    return np.stack([north, east, down], axis=-1)


def gravity_ecef(r: np.ndarray) -> np.ndarray:
    """Gravitation (J2) plus centrifugal acceleration, ECEF, m/s^2; r is (..., 3)."""
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    rr = np.sqrt(x * x + y * y + z * z)
    k = 1.5 * J2 * (A / rr) ** 2
    zr2 = (z / rr) ** 2
    g = -GM / rr ** 3
    gx = g * x * (1.0 + k * (1.0 - 5.0 * zr2))
    gy = g * y * (1.0 + k * (1.0 - 5.0 * zr2))
    gz = g * z * (1.0 + k * (3.0 - 5.0 * zr2))
    w2 = OMEGA_E ** 2
    return np.stack([gx + w2 * x, gy + w2 * y, gz], axis=-1)


def rot_z(angle: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation about z by angle (active)."""
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def euler_to_dcm(yaw, pitch, roll) -> np.ndarray:
    """C_nb (..., 3, 3) for z-y-x yaw, pitch, roll (body forward-right-down to NED)."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    return np.stack([
        np.stack([cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy], -1),
        np.stack([cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy], -1),
        np.stack([-sp, sr * cp, cr * cp], -1)], -2)


def dcm_to_quat(c: np.ndarray) -> np.ndarray:
    """Hamilton quaternion (w, x, y, z) of DCMs (..., 3, 3), w >= 0 (via the largest diagonal term)."""
    c = np.asarray(c)
    tr = np.trace(c, axis1=-2, axis2=-1)
    cand = np.stack([tr, c[..., 0, 0], c[..., 1, 1], c[..., 2, 2]], -1)
    k = np.argmax(cand, -1)
    q = np.empty(c.shape[:-2] + (4,))
    m = k == 0
    s = np.sqrt(1.0 + tr[m]) * 2
    q[m] = np.stack([0.25 * s, (c[m, 2, 1] - c[m, 1, 2]) / s, (c[m, 0, 2] - c[m, 2, 0]) / s,
                     (c[m, 1, 0] - c[m, 0, 1]) / s], -1)
    for i, (a, b, d) in enumerate(((0, 1, 2), (1, 2, 0), (2, 0, 1)), start=1):
        m = k == i
        s = np.sqrt(1.0 + c[m, a, a] - c[m, b, b] - c[m, d, d]) * 2
        comp = np.empty((int(m.sum()), 4))
        comp[:, 0] = (c[m, d, b] - c[m, b, d]) / s
        comp[:, 1 + a] = 0.25 * s
        comp[:, 1 + b] = (c[m, a, b] + c[m, b, a]) / s
        comp[:, 1 + d] = (c[m, a, d] + c[m, d, a]) / s
        q[m] = comp
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def dcm_to_rotvec(c: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) of DCMs, accurate for small angles."""
    q = dcm_to_quat(c)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(s > 1e-12, angle / np.where(s > 0, s, 1.0), 2.0 / np.maximum(q[..., 0], 1e-300))
    return v * k[..., None]
