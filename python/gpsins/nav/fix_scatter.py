"""GNSS error figures measured at a standstill, as a campaign can measure them without a
reference: while the antenna stands still, the receiver's fixes scatter about their mean by
their error's time-correlated part (multipath, atmosphere residuals: correlated over seconds
to minutes), which a white fix model (UERE x DOP, every fix independent) leaves out. From
that scatter: the correlated part's sigma per north/east/down axis, its correlation time
(the first lag where the autocorrelation falls below 1/e) and the range error it stands for
(scatter / DOP); and the filter keys that model it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Scatter:
    sigma_ned_m: np.ndarray  # (3,) the fixes' spread about their mean
    tau_s: float  # correlation time, mean over the axes
    range_error_m: float  # sqrt(sum sigma^2 / mean(HDOP^2 + VDOP^2))


def _ned_rotation(r_ecef: np.ndarray) -> np.ndarray:
    x, y, z = r_ecef
    lon = np.arctan2(y, x)
    lat = np.arctan2(z, np.hypot(x, y) * (1.0 - 6.69437999014e-3))  # geodetic to well below 1e-3 rad
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return np.array([[-sl * co, -sl * so, cl], [-so, co, 0.0], [-cl * co, -cl * so, -sl]])


def measure(fixes: np.ndarray, t0: float, t1: float) -> Scatter:
    """fixes: (m, 10) [t, r xyz, v xyz, hdop, vdop, mode] (sim.fix_table's layout), sampled
    evenly (the lag unit is the fix interval); [t0, t1): a standstill."""
    m = (fixes[:, 0] >= t0) & (fixes[:, 0] < t1) & (fixes[:, 9] > 0)
    if m.sum() < 10:
        raise ValueError(f"{int(m.sum())} fixes between {t0} and {t1} s: too few for a scatter")
    r = fixes[m, 1:4]
    d = (r - r.mean(0)) @ _ned_rotation(r.mean(0)).T
    sigma = d.std(0)
    step = float(np.median(np.diff(fixes[m, 0])))
    taus = []
    for k in range(3):
        x = d[:, k] - d[:, k].mean()
        ac = np.correlate(x, x, "full")[len(x) - 1:] / (x @ x)
        below = np.nonzero(ac < np.exp(-1.0))[0]
        taus.append((below[0] if len(below) else len(x)) * step)
    dop2 = np.mean(fixes[m, 7] ** 2 + fixes[m, 8] ** 2)
    return Scatter(sigma, float(np.mean(taus)), float(np.sqrt(np.sum(sigma ** 2) / dop2)))


def filter_overrides(sc: Scatter, mode: str, white_uere_m: float = 2.0, middle_elevation_deg: float = 30.0) -> dict:
    """Loose: the fix-error states with the scatter's sigmas and time (white part white_uere_m,
    the preset's split). Tight: the pseudoranges' correlated variance, its zenith sigma the range
    error times sin(middle_elevation_deg) (the model grows as 1 / sin(elevation))."""
    if mode == "tight":
        return {"pseudorange_error_gm_sigma_m": sc.range_error_m * np.sin(np.radians(middle_elevation_deg)),
                "pseudorange_error_gm_tau_s": sc.tau_s}
    return {"fix_uere_m": white_uere_m, "fix_error_gm_sigma_m": [float(x) for x in sc.sigma_ned_m],
            "fix_error_gm_tau_s": sc.tau_s}
