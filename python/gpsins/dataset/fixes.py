"""A data set's GNSS fixes for the filter: sigmas from their quality (RTKLIB's Q) where the source
gives none or too small ones, the fix table, and the velocity's sigma and lag.
"""

from __future__ import annotations


import numpy as np

from .. import _core
from ..evaluate import c_en
from ..formats.common import Fixes


# Fix quality (RTKLIB's Q) -> name, and the 1-sigma (horizontal per axis, vertical) a fix of that quality gets
# at least: stated sigmas are formal and ignore what the filter cannot see (antenna offsets of a few cm,
# multipath, a float ambiguity's bias), and a zero must not make a fix absolute. Then the sigma used when the
# file states none.
Q_NAMES = {1: "fix", 2: "float", 3: "sbas", 4: "dgps", 5: "single", 6: "ppp", 0: "unknown"}
SIGMA_FLOOR_M = {"fix": (0.02, 0.03), "float": (0.15, 0.3), "sbas": (0.7, 1.4), "dgps": (0.5, 1.0),
                 "single": (1.5, 3.0), "ppp": (0.05, 0.1), "unknown": (0.02, 0.03)}
SIGMA_DEFAULT_M = {"fix": (0.05, 0.1), "float": (0.5, 1.0), "sbas": (1.5, 3.0), "dgps": (1.0, 2.0),
                   "single": (3.0, 6.0), "ppp": (0.2, 0.4), "unknown": (3.0, 6.0)}
VELOCITY_SIGMA_FLOOR_MPS = 0.02


def fix_sigmas(fixes: Fixes, floor_m: dict | None = None, default_m: dict | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal (per axis) and vertical 1-sigma of every fix: the stated sigmas (north and east pooled)
    where finite, else the default for its quality, never below the floor for its quality."""
    floor_m, default_m = {**SIGMA_FLOOR_M, **(floor_m or {})}, {**SIGMA_DEFAULT_M, **(default_m or {})}
    names = [Q_NAMES.get(int(q), "unknown") for q in fixes.q]
    fl = np.array([floor_m[n] for n in names], float).reshape(-1, 2)
    de = np.array([default_m[n] for n in names], float).reshape(-1, 2)
    s = np.asarray(fixes.sigma_ned_m, float).reshape(-1, 3)
    h = np.sqrt((s[:, 0] ** 2 + s[:, 1] ** 2) / 2.0)
    v = np.abs(s[:, 2])
    h = np.where(np.isfinite(h), h, de[:, 0])
    v = np.where(np.isfinite(v), v, de[:, 1])
    return np.maximum(h, fl[:, 0]), np.maximum(v, fl[:, 1])


def fix_table(fixes: Fixes, t0: float, fix_uere_m: float, floor_m: dict | None = None,
              default_m: dict | None = None, velocity_floor_mps: float = VELOCITY_SIGMA_FLOOR_MPS) -> np.ndarray:
    """The filter's (m, 16) fixes [t - t0, r xyz, v xyz (NaN: none), hdop, vdop, 2 (3D), sigma n e d (m),
    sigma vn ve vd (m/s)].

    Position sigmas from ``fix_sigmas`` (north and east pooled, floored); hdop/vdop are the DOPs those
    stand for with this UERE (sqrt(2) sigma_h / uere, sigma_v / uere). Velocity sigmas per fix as stated,
    floored (NaN where none is stated: the filter's ``fix_velocity_sigma_mps`` then)."""
    h, v = fix_sigmas(fixes, floor_m, default_m)
    n = len(fixes)
    sv = np.full((n, 3), np.nan) if fixes.sigma_v_ned_mps is None else \
        np.abs(np.asarray(fixes.sigma_v_ned_mps, float).reshape(-1, 3))
    sv = np.where(np.isfinite(sv), np.maximum(sv, velocity_floor_mps), np.nan)
    return np.column_stack([fixes.t_abs - t0, fixes.r_ecef, fixes.v_ecef(), np.sqrt(2.0) * h / fix_uere_m,
                            v / fix_uere_m, np.full(n, 2.0), h, h, v, sv]).reshape(-1, 16)


def velocity_sigma(fixes: Fixes, floor_mps: float = VELOCITY_SIGMA_FLOOR_MPS) -> float | None:
    """The velocity sigma for fixes that state none (per-fix sigmas travel in the fix table): the median
    of the stated per-axis sigmas of the fixes with a velocity, floored; None when no fix has a velocity."""
    if fixes.v_ned_mps is None:
        return None
    has = np.isfinite(fixes.v_ned_mps).all(1)
    if not has.any():
        return None
    s = fixes.sigma_v_ned_mps[has] if fixes.sigma_v_ned_mps is not None else np.full((has.sum(), 3), np.nan)
    s = s[np.isfinite(s)]
    return float(max(np.median(s), floor_mps)) if len(s) else 0.1


VELOCITY_LAG_MIN_EPOCHS = 40  # RTK-fixed epochs with both neighbours fixed that a measured lag needs


def velocity_lag(fixes: Fixes, min_epochs: int = VELOCITY_LAG_MIN_EPOCHS) -> dict | None:
    """How long before its time a fix's velocity applies, measured from the fixes' own positions. Between
    two evenly spaced RTK-fixed epochs, a velocity v_k that is the antenna's velocity at t_k - lag, taken
    over the interval dt before t_k (rectangle rule), moves the antenna by v_k dt = r(t_k + d) - r(t_k-1 + d)
    with d = dt/2 - lag, i.e. by the positions' difference plus d times the velocity's change over an
    interval, taken from the neighbours (v_k+1 - v_k-1) / 2 so that no noise is on both sides. Least squares
    over the horizontal components gives d, so the lag (0: the fix's instant; dt/2: the mean over the
    interval just ended); the velocities' noise can only shrink d (lag towards dt/2) by its share of that
    change's variance (0.045 on the simulator's 5 Hz drive). None when the fixes have no velocities or too
    few fixed epochs (standalone positions are too noisy to tell)."""
    if fixes.v_ned_mps is None or len(fixes) < 3:
        return None
    t, q = np.asarray(fixes.t_abs, float), np.asarray(fixes.q)
    v = np.asarray(fixes.v_ned_mps, float)
    r = np.asarray(fixes.r_ecef, float)
    dt = np.diff(t)
    good = (q == 1) & np.isfinite(v).all(1)
    ok = good[1:-1] & good[:-2] & good[2:] & (dt[:-1] > 0) & (np.abs(dt[1:] - dt[:-1]) <= 0.05 * dt[:-1])
    if ok.sum() < min_epochs:
        return None
    k = np.flatnonzero(ok) + 1
    llh = _core.ecef_to_geodetic(r[k])
    c = c_en(llh[:, 0], llh[:, 1])  # NED -> ECEF per epoch
    moved = np.einsum("nji,nj->ni", c, r[k] - r[k - 1])[:, :2]
    y = v[k, :2] * dt[k - 1, None] - moved
    x = (v[k + 1, :2] - v[k - 1, :2]) / 2.0
    if not np.sum(x * x) > 0:
        return None
    d = float(np.sum(x * y) / np.sum(x * x))
    step = float(np.median(dt[k - 1]))
    rms = lambda e: float(np.sqrt(np.mean(np.sum(e * e, 1) / 2.0)) / step)  # noqa: E731 (as a velocity)
    return {"lag_s": step / 2.0 - d, "epochs": int(len(k)), "interval_s": step,
            "rms_mps": rms(y - d * x), "rms_mps_at_zero_lag": rms(y - step / 2.0 * x)}
