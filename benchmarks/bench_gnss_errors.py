"""The simulated receiver's correlated fix errors, measured against truth, and the
Gauss-Markov figures the filter's preset takes from them.

    python benchmarks/bench_gnss_errors.py [SCENARIO] [SEEDS] [--sources]   # default: long 3

For each seed the receiver's 3D fixes are compared with the true antenna position
(north, east, down) and divided by their DOP on that axis (HDOP / sqrt 2 north and east,
VDOP down, as the filter scales a fix's sigmas): the error per unit of DOP, in metres
like a UERE. First the table of that ratio by geometry (it hardly changes from HDOP 1 to
HDOP 80: both the white and the correlated parts grow with the DOP, so the filter carries
the correlated part per unit of DOP too; 2D fixes, with their held height's error, are
worse). Then, per axis, the autocovariance of the ratio over the lags 0..300 s, averaged
over the seeds and fitted with white + first-order Gauss-Markov:

    C(0) = w^2 + s^2,   C(lag) = s^2 exp(-lag / tau)  (lag > 0)

w is the white UERE, s the correlated one (fix_error_gm_sigma_m with
fix_error_gm_dop_scaled), tau its correlation time. Then the two-part fit over lags
1..120 s the preset uses: white + a fast and a slow Gauss-Markov part (one fast and one slow
tau for all axes); the filter carries the slow part as states (fix_error_gm_*) and the
fast part in each fix's R (fix_error_fast_*). The same is done with the
multipath, the atmosphere residuals, or the code noise switched off in turn, to say which
source gives which part. Nothing here reads the filter: the simulator is the truth.
"""

import dataclasses
import sys

import numpy as np

from gpsins import sim
from gpsins.sim import scenario
from gpsins.evaluate.gnss_errors import (autocovariance_sums, fit_white_gauss_markov as fit,
                                         fit_white_two_gauss_markov, fix_errors_per_dop)
from gpsins.sim import earth

MAX_LAG_S = 300


def by_geometry(sims) -> float:
    """RMS of the error per unit of DOP by HDOP class, and of the 2D fixes (returned: their horizontal one)."""
    rows, out = [], float("nan")
    for s in sims:
        for f in s.gnss.fixes:
            if f.mode in (2, 3):
                truth = s.truth.position_at(np.array([f.t]))[0]
                d = earth.ecef_to_ned_matrix(f.llh[0], f.llh[1]).T @ (f.r_ecef - truth)
                rows.append((f.mode, f.hdop, f.vdop, *d))
    r = np.array(rows)
    for name, sel in (("3D, HDOP <= 2", (r[:, 0] == 2) & (r[:, 1] <= 2)),
                      ("3D, HDOP 2..10", (r[:, 0] == 2) & (r[:, 1] > 2) & (r[:, 1] <= 10)),
                      ("3D, HDOP > 10", (r[:, 0] == 2) & (r[:, 1] > 10)), ("2D", r[:, 0] == 3)):
        x = r[sel]
        if len(x):
            h = np.sqrt(np.mean((x[:, 3] ** 2 + x[:, 4] ** 2) / x[:, 1] ** 2))
            v = np.sqrt(np.mean(x[:, 5] ** 2 / x[:, 2] ** 2)) if name != "2D" else float("nan")
            print(f"  {name:15s} {len(x):5d} fixes, median HDOP {np.median(x[:, 1]):5.1f}: horizontal error per unit "
                  f"of DOP {h:.2f} m, down {v:.2f} m")
            out = h if name == "2D" else out
    return out


def measure(sc, seeds: int, label: str) -> dict:
    sums, counts, sims = 0.0, 0.0, []
    for seed in range(seeds):
        s = sim.simulate(sc, seed)
        t, e, _ = fix_errors_per_dop(s)
        a, n = autocovariance_sums(t, e, MAX_LAG_S)
        sums, counts = sums + a, counts + n
        sims.append(s)
    c = sums[counts > 0] / counts[counts > 0, None]
    print(f"{label}:")
    out = {"2D": by_geometry(sims)}
    for i, axis in enumerate("NED"):
        w, g, tau = fit(c[:, i])
        out[axis] = (w, g, tau)
        lag = {L: c[L, i] / c[0, i] for L in (1, 10, 30, 60, 120, 300) if L < len(c)}
        print(f"  {axis}: per unit of DOP, RMS {np.sqrt(c[0, i]):.2f} m = white {w:.2f} m + Gauss-Markov {g:.2f} m, "
              f"tau {tau:.0f} s; correlation " + ", ".join(f"{L} s {v:.2f}" for L, v in lag.items()))
    two = fit_white_two_gauss_markov(c[:, :3], 120)
    out["two"] = two
    print(f"  white + fast + slow Gauss-Markov over lags 1..120 s (taus shared by the axes): white "
          f"{np.round(two['white'], 2)} m, fast {np.round(two['fast'], 2)} m tau {two['tau_fast']:.1f} s, slow "
          f"{np.round(two['slow'], 2)} m tau {two['tau_slow']:.1f} s (N, E, D per unit of DOP; RMS residual "
          f"{two['rms_residual']:.3f} m^2)")
    return out


def pseudorange_errors(sc, seeds: int) -> None:
    """The pseudoranges' correlated part for the tight filter: per tracked satellite at the
    receiver's 10 Hz, the multipath times sin(elevation) (its size at zenith) fitted with a
    Gauss-Markov process over lags 0..60 s; and the atmosphere's residual after the receiver's
    corrections (Klobuchar, standard troposphere), whose correlation lasts minutes."""
    from gpsins.sim import atmosphere

    lags = np.arange(0, 601, 10)  # epochs of 0.1 s
    sums, counts, atm = np.zeros(len(lags)), np.zeros(len(lags)), []
    for seed in range(seeds):
        g = sim.simulate(sc, seed).gnss
        x = np.where(g.tracked, g.multipath_m * np.sin(g.elevation), np.nan)
        for j, lag in enumerate(lags):
            p = x[:len(x) - lag] * x[lag:]
            sums[j] += np.nansum(p)
            counts[j] += np.isfinite(p).sum()
        lat = np.radians(sc.start.lat_deg)
        lon = np.radians(sc.start.lon_deg)
        klob = atmosphere.klobuchar_m(g.ion_alpha, g.ion_beta, lat, lon, g.azimuth, g.elevation,
                                      (sc.start.gps_tow_s + g.t)[:, None])
        resid = g.iono_m - klob + g.trop_m - atmosphere.receiver_trop_m(g.elevation, sc.start.height_m)
        atm.append(np.where(g.tracked, resid, np.nan))
    c = sums / counts
    w, s_gm, tau_s = fit(c)  # c[j]: lag j seconds
    a = np.concatenate(atm)
    print(f"pseudoranges: multipath at zenith {np.sqrt(c[0]):.2f} m, Gauss-Markov fit {s_gm:.2f} m, tau "
          f"{tau_s:.0f} s (pseudorange_error_gm_sigma_m, _tau_s); atmosphere residual RMS "
          f"{np.sqrt(np.nanmean(a ** 2)):.2f} m, mean {np.nanmean(a):.2f} m (common to all satellites in large part)")


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    name = args[0] if args else "long"
    seeds = int(args[1]) if len(args) > 1 else 3
    sc = scenario.load(name)
    g = sc.gnss
    f = measure(sc, seeds, f"{name}, {seeds} seeds, every error source")
    uere_h = np.hypot(f["N"][0], f["E"][0]) / np.sqrt(2)
    gm_h = np.hypot(f["N"][1], f["E"][1]) / np.sqrt(2)
    print(f"for the filter (horizontal axes pooled; fix_error_gm_dop_scaled): fix_uere_m ~ {uere_h:.2f} "
          f"(down {f['D'][0]:.2f}), fix_error_gm_sigma_m ~ [{gm_h:.2f}, {gm_h:.2f}, {f['D'][1]:.2f}], "
          f"fix_error_gm_tau_s ~ {np.mean([f[a][2] for a in 'NED']):.0f}; 2D fixes, the rest of their error as "
          f"white: fix_uere_2d_m ~ {np.sqrt(max(f['2D'] ** 2 - gm_h ** 2, 0.0)):.2f}")
    two = f["two"]
    print(f"two-part model: fix_uere_m ~ {two['white'][0]:.2f} (north's), fix_error_gm_sigma_m ~ "
          f"{np.round(two['slow'], 2).tolist()}, fix_error_gm_tau_s ~ {two['tau_slow']:.1f}, fix_error_fast_sigma_m ~ "
          f"{np.round(two['fast'], 2).tolist()}, fix_error_fast_tau_s ~ {two['tau_fast']:.1f}")
    # The preset's way: the slow part (orbit and clock errors) outlasts the drive, and carried
    # as states with the fast part inflated in R the filter is too cautious and less accurate; so the
    # fast part goes to the states and the slow one to a white R.
    fast_h, slow_h = (np.hypot(two[k][0], two[k][1]) / np.sqrt(2) for k in ("fast", "slow"))
    print(f"preset mapping: fix_error_gm_sigma_m ~ {np.round(two['fast'], 2).tolist()}, fix_error_gm_tau_s ~ "
          f"{two['tau_fast']:.1f}, fix_error_fast_sigma_m ~ {np.round(two['slow'], 2).tolist()}, "
          "fix_error_fast_tau_s = 0; "
          f"fix_uere_2d_m ~ {np.sqrt(max(f['2D'] ** 2 - fast_h ** 2 - slow_h ** 2, 0.0)):.2f}")
    pseudorange_errors(sc, seeds)
    if "--sources" not in sys.argv:
        return
    for label, change in (("without multipath", dict(multipath_m=0.0)),
                          ("without atmosphere residuals", dict(iono_scale=1.0, iono_variation=0.0,
                                                                trop_wet_zenith_m=0.0)),
                          ("without code noise", dict(code_noise_m=0.0))):
        measure(dataclasses.replace(sc, gnss=dataclasses.replace(g, **change)), seeds, label)


if __name__ == "__main__":
    main()
