"""The white and time-correlated parts of a receiver's errors, measured against truth:
what the filter's fix-error model (fix_uere_m, fix_error_gm_*) takes its figures
from. Reads the simulator's receiver output and truth only, never the filter."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from ..sim import earth


def fix_errors_per_dop(s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, error NED per unit of DOP (n, 3), DOP per axis (n, 3)) of a simulation's 3D fixes:
    the error against the true antenna position divided by HDOP / sqrt 2 (north, east) and VDOP
    (down), as the filter scales a fix's sigmas."""
    fx = [f for f in s.gnss.fixes if f.mode == 2]
    t = np.array([f.t for f in fx])
    d = np.array([f.r_ecef for f in fx]) - s.truth.position_at(t)
    ned = np.array([earth.ecef_to_ned_matrix(f.llh[0], f.llh[1]).T @ x for f, x in zip(fx, d)])
    dop = np.array([[f.hdop / np.sqrt(2), f.hdop / np.sqrt(2), f.vdop] for f in fx])
    return t, ned / dop, dop


def autocovariance_sums(t: np.ndarray, e: np.ndarray, max_lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Per column of e, sums of e(t) e(t + lag) at whole-second lags 0..max_lag and their
    counts (samples at 1 Hz with gaps). The mean is kept: a bias is error too."""
    k = np.round(t - t[0]).astype(int)
    grid = np.full((k[-1] + 1, e.shape[1]), np.nan)
    grid[k] = e
    have = np.isfinite(grid[:, 0])
    g = np.where(have[:, None], grid, 0.0)
    sums, counts = np.zeros((max_lag + 1, e.shape[1])), np.zeros(max_lag + 1)
    for lag in range(min(max_lag, len(g) - 1) + 1):
        sums[lag] = (g[:len(g) - lag] * g[lag:]).sum(axis=0)
        counts[lag] = (have[:len(g) - lag] & have[lag:]).sum()
    return sums, counts


def fit_white_gauss_markov(c: np.ndarray) -> tuple[float, float, float]:
    """(white sigma, Gauss-Markov sigma, tau in lag units) of an autocovariance c[lag]:
    c(0) = w^2 + s^2, c(lag) = s^2 exp(-lag / tau) for lag > 0 (least squares over lag > 0)."""
    lags = np.arange(1, len(c))

    def resid(p):
        s2, tau = np.exp(p)
        return s2 * np.exp(-lags / tau) - c[1:]

    s2, tau = np.exp(least_squares(resid, np.log([max(c[1], 1e-6), 30.0])).x)
    return float(np.sqrt(max(c[0] - s2, 0.0))), float(np.sqrt(s2)), float(tau)


def fit_white_two_gauss_markov(c: np.ndarray, max_lag: int = 120) -> dict:
    """White + fast + slow Gauss-Markov fit of autocovariances c[lag, axis] over lags 1..max_lag,
    one fast and one slow correlation time shared by the axes (as the filter carries them):
    C(lag) = f^2 exp(-lag / tau_f) + s^2 exp(-lag / tau_s), white^2 = C(0) - f^2 - s^2.
    Returns per-axis sigmas (white, fast, slow) and the two taus in lag units."""
    lags = np.arange(1, min(max_lag, len(c) - 1) + 1)
    y = c[lags].T

    def model(p):
        tf, ts = np.exp(p[:2])
        f2, s2 = np.exp(p[2:2 + len(y)]), np.exp(p[2 + len(y):])
        return f2[:, None] * np.exp(-lags / tf) + s2[:, None] * np.exp(-lags / ts)

    start = np.log(np.r_[5.0, 40.0, 0.5 * np.maximum(y[:, 0], 1e-6), 0.5 * np.maximum(y[:, 0], 1e-6)])
    p = least_squares(lambda q: (model(q) - y).ravel(), start).x
    tf, ts = np.exp(p[:2])
    f2, s2 = np.exp(p[2:2 + len(y)]), np.exp(p[2 + len(y):])
    if tf > ts:  # name them by speed
        tf, ts, f2, s2 = ts, tf, s2, f2
    return {"white": np.sqrt(np.maximum(c[0] - f2 - s2, 0.0)), "fast": np.sqrt(f2), "slow": np.sqrt(s2),
            "tau_fast": float(tf), "tau_slow": float(ts),
            "rms_residual": float(np.sqrt(np.mean((model(p) - y) ** 2)))}
