"""Where the tight filter's caution under model mismatch comes from:
`python benchmarks/bench_pr_budget.py [seeds]` (default 3).

Per seed, the mismatch run of bench_mismatch.py (tight, preset GNSS errors) split into attitude,
velocity and position NEES (3 each), and the simulated pseudorange errors left after the
corrections the filter makes (broadcast Klobuchar, a standard troposphere) against the variance
the filter gives them: the white model (code, code bias, half the ionosphere model, troposphere),
the signal-in-space part (the preset's sigma; once the broadcast URA in the white part)
and the correlated part's stationary variance. Reported as the mean of error^2 / variance (1 for a
matched model) with the preset's model and with the URA instead, and the mean squared error by
component (m^2); the simulated orbit/clock error is the pseudorange's change when it is switched off.
Measured (seeds 0-1): error^2 / model 0.70-0.77 with the preset, 0.31-0.34 with the URA.
"""

import sys

import numpy as np

from gpsins import _core, evaluate, sim
from gpsins.sim import scenario
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.sim import atmosphere, unit


def main(seeds: int = 3) -> None:
    ds = unit.Datasheet()
    cfg = nav_config.load_config(None, {**unit.filter_overrides(ds), "mode": "tight"})
    gm, sis_sigma = cfg["pseudorange_error_gm_sigma_m"], cfg["pseudorange_sis_sigma_m"]
    for seed in range(seeds):
        sc = scenario.load("default")
        sc.imu = unit.draw_unit(ds, np.random.default_rng([seed, 21]), sc.imu)
        s = sim.simulate(sc, seed=seed)
        sis_model = sc.gnss.sis_error_m
        sc.gnss.sis_error_m = 0.0
        sis_err = s.gnss.pseudorange_m - sim.simulate(sc, seed=seed).gnss.pseudorange_m
        sc.gnss.sis_error_m = sis_model
        sol = flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True, **sim.tight_inputs(s))
        tr = s.truth
        err = evaluate.nav_errors(sol, evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb))
        sel = sol.t >= sol.t[np.argmax(sol.heading_known)]
        e, P = err.e9[sel], sol.covariance[sel][:, :9, :9]
        part = [float(evaluate.nees(e[:, i:i + 3], P[:, i:i + 3, i:i + 3]).mean()) for i in (0, 3, 6)]

        g = s.gnss
        el = g.elevation
        ok = np.isfinite(g.pseudorange_m) & (el > np.radians(10.0))
        lat = np.interp(g.t, tr.t, tr.lat)[:, None] * np.ones_like(el)
        lon = np.interp(g.t, tr.t, tr.lon)[:, None] * np.ones_like(el)
        h = np.interp(g.t, tr.t, tr.h)[:, None] * np.ones_like(el)
        tow = (sc.start.gps_tow_s + g.t)[:, None] * np.ones_like(el)
        klob = atmosphere.klobuchar_m(g.ion_alpha, g.ion_beta, lat, lon, g.azimuth, el, tow)
        iono_res = (g.iono_m - klob)[ok]
        trop_res = (g.trop_m - atmosphere.receiver_trop_m(el, h))[ok]
        mp = g.multipath_m[ok]
        sis = sis_err[ok]
        total = iono_res + trop_res + mp + sis
        sin_el = np.sin(el[ok])
        code_sim = sc.gnss.code_noise_m ** 2 / sin_el
        var_white = np.array([_core.gnss.pseudorange_variance_m2(a, 0.0, k) for a, k in zip(el[ok], klob[ok])])
        var_gm = (gm / np.maximum(sin_el, 0.1)) ** 2
        e2 = total ** 2 + code_sim  # the white code noise enters by its simulated variance
        print(f"seed {seed}: NEES att/vel/pos {part[0]:.2f} / {part[1]:.2f} / {part[2]:.2f} (3 each); "
              f"pseudorange error^2 / model {np.mean(e2 / (var_white + sis_sigma ** 2 + var_gm)):.3f} preset, "
              f"{np.mean(e2 / (var_white + 2.4 ** 2 + var_gm)):.3f} with the URA; "
              f"mean sq. m^2: iono {np.mean(iono_res ** 2):.2f} trop {np.mean(trop_res ** 2):.3f} "
              f"multipath {np.mean(mp ** 2):.2f} code {np.mean(code_sim):.2f} orbit/clock {np.mean(sis ** 2):.2f}; "
              f"model white {np.mean(var_white):.2f} signal in space {sis_sigma ** 2:.2f} (URA {2.4 ** 2:.2f}) "
              f"correlated {np.mean(var_gm):.2f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
