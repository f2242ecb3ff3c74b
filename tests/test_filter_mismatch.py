"""The filters under model mismatch: the simulated unit is drawn from a datasheet and a
calibration with its uncertainty (scale factors off their calibration, bias residuals,
misalignment the filter knows by its sigma only, g-sensitivity it does not model, noise
coefficients off the datasheet's), and the filter is configured from that description
alone, never from the drawn unit (sim.unit). Consistency is judged on the simulator's truth."""

import numpy as np
import pytest

from gpsins import evaluate, sim
from gpsins.sim import scenario
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.sim import unit

SEEDS = 5


def _truth(s):
    tr = s.truth
    return evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb)


@pytest.fixture(scope="module")
def runs():
    ds = unit.Datasheet()
    cfg = nav_config.load_config(None, unit.filter_overrides(ds))
    out = []
    for seed in range(SEEDS):
        sc = scenario.load("default")
        sc.imu = unit.draw_unit(ds, np.random.default_rng([seed, 21]), sc.imu)
        s = sim.simulate(sc, seed=seed)
        sol = flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True)
        out.append((s, sol, evaluate.nav_errors(sol, _truth(s))))
    return ds, out


def test_the_unit_really_differs_from_the_filters_model(runs):
    ds, out = runs
    for s, _, _ in out:
        m, e = s.scenario.imu, s.imu_errors
        sf_off = np.abs(np.diag(e.gyro_matrix) - 1.0 - np.array(ds.gyro_scale_factor_cal))
        assert sf_off.max() > 2e-4  # scale factor off its calibration
        assert e.gyro_g_matrix is not None and np.abs(e.gyro_g_matrix).max() > 1e-5
        assert np.abs(e.gyro_matrix - np.diag(np.diag(e.gyro_matrix))).max() > 1e-4  # misalignment
        ratio = np.array(m.gyro_arw_rad_per_sqrt_s) / np.array(ds.gyro_arw_rad_per_sqrt_s)
        assert np.abs(np.log(ratio)).max() > 0.02  # noise off the datasheet


def test_three_sigma_coverage_under_mismatch(runs):
    """Each of the 9 navigation errors inside 3 sigma at least 95 % of the time after the heading is
    known, pooled over the seeds of the default drive, and at least 85 % on every seed: one 4-minute
    run's yaw error is a handful of independent values. Seed 2's yaw (about 4 deg RMS, inside 3 sigma
    92 % of the time) is not the mismatch: with a noise-free unit without misalignment or
    g-sensitivity it still steps by 2.5 deg at t = 167-173 s, braking on a straight in the half-blocked
    sky (fixes off by 2-6 m, correlated), the only moments its yaw is observable; the bias
    instability's wander adds the rest (3.1 deg RMS with it, 2.3 without, matched unit)."""
    _, out = runs
    worst, inside_all = [], []
    for _, sol, err in out:
        sel = sol.t >= sol.t[np.argmax(sol.heading_known)]
        inside = np.abs(err.e9[sel]) <= 3.0 * sol.sigma[sel, :9]
        inside_all.append(inside)
        worst.append(inside.mean(0).min())
        assert not sol.counters["diverged"]
    pooled = np.concatenate(inside_all).mean(0)
    print(f"3-sigma coverage under mismatch, worst state per seed: {np.round(worst, 3)}, pooled per state "
          f"{np.round(pooled, 3)}")
    assert pooled.min() >= 0.95 and min(worst) >= 0.85, (pooled, worst)


def _nees_from_heading(sol, err) -> float:
    """The run's time-averaged 9-state NEES from the first known heading to the end."""
    sel = sol.t >= sol.t[np.argmax(sol.heading_known)]
    return float(evaluate.nees(err.e9[sel], sol.covariance[sel][:, :9, :9]).mean())


def test_nees_under_mismatch_inside_its_band(runs):
    """Time-averaged NEES of the 9 navigation states over the seeds, from the first known
    heading to the end, inside the two-sided 95 % band of a 5-run average (Bar-Shalom)."""
    _, out = runs
    per_seed = []
    for _, sol, err in out:
        per_seed.append(_nees_from_heading(sol, err))
    lo, hi = evaluate.nees_band(9, SEEDS)
    avg = float(np.mean(per_seed))
    print(f"NEES under mismatch: per seed {np.round(per_seed, 2)}, average {avg:.2f}, band {lo:.2f}..{hi:.2f}")
    assert lo <= avg <= hi


def test_tight_nees_under_mismatch_with_correlated_pseudorange_errors(runs):
    """The tight filter on the same drives, its pseudoranges' correlated part modelled
    (sim.unit.ReceiverErrors): NEES inside the 5-run band. With white pseudoranges at 1 Hz
    these seeds average 14.0, outside (multipath and atmosphere residuals stay correlated
    over tens of seconds; bench_mismatch: 20 seeds white 12.82, correlated 8.40)."""
    ds, out = runs
    cfg = nav_config.load_config(None, {**unit.filter_overrides(ds), "mode": "tight",
                                        **unit.receiver_overrides(unit.ReceiverErrors(), "tight")})
    per_seed = []
    for s, _, _ in out:
        sol = flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True, **sim.tight_inputs(s))
        assert not sol.counters["diverged"]
        err = evaluate.nav_errors(sol, _truth(s))
        per_seed.append(_nees_from_heading(sol, err))
    lo, hi = evaluate.nees_band(9, SEEDS)
    avg = float(np.mean(per_seed))
    print(f"tight NEES under mismatch: per seed {np.round(per_seed, 2)}, average {avg:.2f}, band {lo:.2f}..{hi:.2f}")
    assert lo <= avg <= hi
