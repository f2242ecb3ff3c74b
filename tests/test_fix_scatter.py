"""Fix-error figures from a standstill's scatter (gpsins.fix_scatter) on synthetic fixes whose
error is a known first-order Gauss-Markov process per north/east/down axis."""

import numpy as np

from gpsins.nav import fix_scatter
from gpsins.sim import earth


def test_scatter_recovers_sigma_and_correlation_time():
    rng = np.random.default_rng(4)
    n, tau, sigma = 3000, 15.0, np.array([3.0, 1.5, 4.0])
    phi = np.exp(-1.0 / tau)
    e = np.zeros((n, 3))
    e[0] = rng.normal(0.0, sigma)
    for k in range(1, n):
        e[k] = phi * e[k - 1] + rng.normal(0.0, sigma * np.sqrt(1.0 - phi * phi))
    lat, lon = np.radians(59.3), np.radians(18.1)
    r0 = earth.geodetic_to_ecef(lat, lon, 25.0)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    c_en = np.array([[-sl * co, -so, -cl * co], [-sl * so, co, -cl * so], [cl, 0.0, -sl]])
    fixes = np.zeros((n, 10))
    fixes[:, 0] = np.arange(n)
    fixes[:, 1:4] = r0 + e @ c_en.T
    fixes[:, 7], fixes[:, 8], fixes[:, 9] = 1.0, 1.5, 2
    est = fix_scatter.measure(fixes, 0.0, float(n))
    assert np.allclose(est.sigma_ned_m, sigma, rtol=0.2), est
    assert 10.0 < est.tau_s < 20.0, est
    assert np.isclose(est.range_error_m, np.sqrt(np.sum(est.sigma_ned_m ** 2) / (1.0 + 1.5 ** 2)))
    loose = fix_scatter.filter_overrides(est, "loose")
    assert loose["fix_error_gm_tau_s"] == est.tau_s and np.allclose(loose["fix_error_gm_sigma_m"], est.sigma_ned_m)
    tight = fix_scatter.filter_overrides(est, "tight")
    assert np.isclose(tight["pseudorange_error_gm_sigma_m"], 0.5 * est.range_error_m)
