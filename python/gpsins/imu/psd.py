"""One-sided power spectral density (Welch) with the report's frequency
averaging (log-spaced bins, the FOI report's section 5.2) and the white-noise level.

Convention: a white rate noise whose Allan coefficient is N (ADEV = N / sqrt(tau))
has the two-sided density N^2 and the one-sided Welch plateau 2 N^2, so
N = sqrt(plateau / 2) (units: (rad/s)^2/Hz -> rad/sqrt(s); eq. 5.10-5.11 convert
to deg/sqrt(h) by 180/pi * 60).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import welch


def psd(y: np.ndarray, rate_hz: float, segment_s: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    y = np.asarray(y, dtype=float)
    nper = int(min(len(y), max(256, segment_s * rate_hz)))
    f, p = welch(y - y.mean(), fs=rate_hz, nperseg=nper, axis=0, detrend="constant", scaling="density")
    return f[1:], p[1:]


def log_average(f: np.ndarray, p: np.ndarray, bins_per_decade: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Average the PSD in log-spaced frequency bins (the report's frequency averaging)."""
    edges = np.logspace(np.log10(f[0]), np.log10(f[-1]) + 1e-9, int(np.log10(f[-1] / f[0]) * bins_per_decade) + 2)
    idx = np.digitize(f, edges) - 1
    fc, pc = [], []
    for k in np.unique(idx):
        m = idx == k
        fc.append(np.exp(np.mean(np.log(f[m]))))
        pc.append(p[m].mean(0))
    return np.array(fc), np.array(pc)


def white_level(f: np.ndarray, p: np.ndarray, band_hz: tuple[float, float] | None = None) -> np.ndarray:
    """Allan N from the PSD plateau (median over the band; default the top half decade below Nyquist/2)."""
    if band_hz is None:
        band_hz = (f[-1] / 10 ** 0.75, f[-1] / 2)
    m = (f >= band_hz[0]) & (f <= band_hz[1])
    return np.sqrt(np.median(p[m], axis=0) / 2.0)
