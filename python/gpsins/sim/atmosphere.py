"""Signal delays for the simulator: the broadcast Klobuchar model (what a
receiver corrects with), the 'true' ionosphere around it, and two
tropospheres (the truth, with more water vapour and a different mapping, and
the simple standard-atmosphere model a receiver applies)."""

from __future__ import annotations

import numpy as np

C = 299792458.0


def klobuchar_m(alpha, beta, lat, lon, az, el, tow) -> np.ndarray:
    """IS-GPS-200 single-frequency L1 delay in metres; angles in rad, tow in s."""
    e = el / np.pi
    psi = 0.0137 / (e + 0.11) - 0.022
    phi_i = np.clip(lat / np.pi + psi * np.cos(az), -0.416, 0.416)
    lam_i = lon / np.pi + psi * np.sin(az) / np.cos(phi_i * np.pi)
    phi_m = phi_i + 0.064 * np.cos((lam_i - 1.617) * np.pi)
    t = np.mod(4.32e4 * lam_i + tow, 86400.0)
    f = 1.0 + 16.0 * (0.53 - e) ** 3
    amp = np.maximum(sum(a * phi_m ** n for n, a in enumerate(alpha)), 0.0)
    per = np.maximum(sum(b * phi_m ** n for n, b in enumerate(beta)), 72000.0)
    x = 2.0 * np.pi * (t - 50400.0) / per
    night = 5e-9
    day = night + amp * (1.0 - x * x / 2.0 + x ** 4 / 24.0)
    return C * f * np.where(np.abs(x) < 1.57, day, night)


def true_iono_m(klob_m, t, prn, scale: float, variation: float, period_s: float) -> np.ndarray:
    """The simulated ionosphere: Klobuchar scaled, with a slow per-satellite variation around it."""
    phase = 0.7 * np.asarray(prn, dtype=float)
    return klob_m * scale * (1.0 + variation * np.sin(2.0 * np.pi * t / period_s + phase))


def _mapping(el):
    """Black and Eisner's mapping function."""
    return 1.001 / np.sqrt(0.002001 + np.sin(el) ** 2)


def true_trop_m(el, lat, h, wet_zenith_m: float) -> np.ndarray:
    pressure = 1013.25 * (1.0 - 2.2557e-5 * h) ** 5.2568
    zhd = 0.0022768 * pressure / (1.0 - 0.00266 * np.cos(2.0 * lat) - 0.00028 * h / 1000.0)
    return (zhd + wet_zenith_m) * _mapping(el)


def receiver_trop_m(el, h) -> np.ndarray:
    """What the simulated receiver applies: a standard atmosphere, exponential in height."""
    return 2.4224 * np.exp(-1.3345e-4 * np.maximum(h, 0.0)) * _mapping(el)
