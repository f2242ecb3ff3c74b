"""The loosely coupled filter against the simulator's truth (its own NumPy models),
published chi-square bands and the report's tables."""

import math
import tomllib

import numpy as np
import pytest

from gpsins import evaluate, sim
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.sim import scenario as scenario_mod
from gpsins.sim.scenario import parse

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}

# 12 s standing, then 63 s of driving with turns, grades and speed changes.
DRIVE = [
    {"label": "stand", "duration_s": 12, "speed_mps": 0},
    {"label": "go", "duration_s": 6, "speed_mps": 9},
    {"label": "right", "duration_s": 10, "turn_deg": 90, "grade_deg": 2},
    {"label": "straight", "duration_s": 8, "speed_mps": 14, "grade_deg": 0},
    {"label": "left", "duration_s": 9, "turn_deg": -60},
    {"label": "slow", "duration_s": 10, "speed_mps": 7, "turn_deg": 30, "grade_deg": -3},
    {"label": "s-bend", "duration_s": 10, "turn_deg": -45, "speed_mps": 11},
    {"label": "last", "duration_s": 10, "turn_deg": 20, "grade_deg": 0},
]


def scenario(segments, **extra):
    return parse({"name": "test", "start": START, "segment": segments, **extra})


def truth_of(s):
    tr = s.truth
    return evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb)


def run_sim(s, overrides=None, **kw):
    cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), **(overrides or {})})
    return flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True, **kw)


@pytest.fixture(scope="module")
def default_run():
    s = sim.simulate(scenario_mod.load("default"), seed=0)
    return s, run_sim(s)


def test_standing_still_levels_to_the_accelerometer_biases_and_learns_the_gyro_biases():
    s = sim.simulate(scenario([{"label": "parked", "duration_s": 120, "speed_mps": 0}]), seed=4)
    cfg = nav_config.load_config(None, sim.imu_noise_truth(s.scenario.imu))
    sol = flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True)
    err = evaluate.nav_errors(sol, truth_of(s))
    end = sol.t > sol.t[-1] - 10.0
    # What levelling sees: the calibrated specific force's mean over the last 10 s, in
    # the filter's body axes, levelled here with NumPy (independent of the core).
    m = s.scenario.imu
    dt = np.diff(s.imu_t).mean()
    f = (s.imu_dv / dt - np.array(m.accel_bias_mps2)) / (1.0 + np.array(m.accel_scale_factor))
    f = f[s.imu_t > s.imu_t[-1] - 10.0]
    f_true = s.truth.f_body[s.truth_at_imu][s.imu_t > s.imu_t[-1] - 10.0]
    # Remove the part the filter can see (the vertical bias) and keep the horizontal one.
    bias = f.mean(0) - f_true.mean(0)
    f_seen = f_true.mean(0) + np.array([bias[0], bias[1], 0.0])
    implied_roll = math.degrees(math.atan2(-f_seen[1], -f_seen[2]) - math.atan2(-f_true.mean(0)[1], -f_true.mean(0)[2]))
    implied_pitch = math.degrees(math.atan2(f_seen[0], math.hypot(f_seen[1], f_seen[2]))
                                 - math.atan2(f_true.mean(0)[0], math.hypot(f_true.mean(0)[1], f_true.mean(0)[2])))
    roll_err, pitch_err = err.ypr_deg[end, 2].mean(), err.ypr_deg[end, 1].mean()
    assert abs(implied_roll) > 0.05 or abs(implied_pitch) > 0.05  # the biases do tilt the solution
    assert abs(roll_err - implied_roll) < 0.1
    assert abs(pitch_err - implied_pitch) < 0.1
    # Gyro biases and the vertical accelerometer bias converge to the truth: the total bias incl. drift,
    # averaged over the last 10 s as the zero-rate updates see it (its fastest bias-instability term,
    # tau 3 s, swings by its 4.7e-4 rad/s within seconds); at rest a g-sensitive gyro adds G f, a
    # constant the filter cannot tell from its bias.
    late = s.imu_t > s.imu_t[-1] - 10.0
    gb_true = (s.imu_errors.gyro_bias_rad_per_s + s.imu_errors.gyro_bias_drift[late].mean(0)) \
        - np.array(m.gyro_bias_rad_per_s)
    if s.imu_errors.gyro_g_matrix is not None:
        gb_true = gb_true + s.imu_errors.gyro_g_matrix @ f_true.mean(0)
    ab_true = (s.imu_errors.accel_bias_mps2 + s.imu_errors.accel_bias_drift[-1]) - np.array(m.accel_bias_mps2)
    g_sig, a_sig = sol.sigma[-1, 9:12], sol.sigma[-1, 12:15]
    assert np.all(np.abs(sol.gyro_bias[-1] - gb_true) < 3 * g_sig)
    assert np.all(g_sig < 0.25 * nav_config.core_config(cfg).gyro_bias_sigma_rad_per_s)
    assert abs(sol.accel_bias[-1, 2] - ab_true[2]) < 3 * a_sig[2]
    assert a_sig[2] < 0.2 * nav_config.core_config(cfg).accel_bias_sigma_mps2[2]
    # The horizontal accelerometer biases are unobservable at rest: their sigma must not shrink
    # (x and y are not exactly horizontal, so allow a little).
    assert np.all(a_sig[:2] > 0.9 * nav_config.core_config(cfg).accel_bias_sigma_mps2[:2])
    # Position within the fix noise: the fixes' own error spread.
    fix = sim.fix_table(s)
    fix = fix[(fix[:, 9] == 2) & (fix[:, 0] > s.truth.t[0]) & (fix[:, 0] < s.truth.t[-1])]
    fix_err = np.linalg.norm(fix[:, 1:4] - truth_of(s).at(fix[:, 0]).r_ecef, axis=1)
    assert np.sqrt(np.mean(err.r_ned[end] ** 2)) * math.sqrt(3) < 1.5 * np.sqrt(np.mean(fix_err ** 2))


def test_default_drive_errors_stay_inside_three_sigma(default_run):
    s, sol = default_run
    err = evaluate.nav_errors(sol, truth_of(s))
    hk = sol.heading_known
    assert hk.mean() > 0.85  # heading from the course within a few seconds of driving off
    inside = np.abs(err.e9[hk]) <= 3.0 * sol.sigma[hk, :9]
    frac = inside.mean(0)
    assert np.all(frac >= 0.95), frac
    assert sol.counters["fixes_rejected"] == 0 and not sol.counters["diverged"]


def nees_over_seeds(solve, seeds=5, span_s=60.0) -> tuple[float, float, float]:
    """Time-averaged NEES of the 9 navigation states over `seeds` runs of DRIVE, each from its
    first known heading for span_s; with the two-sided 95 % band of a `seeds`-run average."""
    sc = scenario(DRIVE)
    runs = []
    for seed in range(seeds):
        s = sim.simulate(sc, seed=seed)
        sol = solve(s)
        err = evaluate.nav_errors(sol, truth_of(s))
        t0 = sol.t[np.argmax(sol.heading_known)]
        sel = (sol.t >= t0) & (sol.t < t0 + span_s)
        assert sel.sum() > 60 * span_s
        runs.append(evaluate.nees(err.e9[sel], sol.covariance[sel][:, :9, :9]))
    n = min(len(r) for r in runs)
    lo, hi = evaluate.nees_band(9, seeds)
    return float(np.mean([r[:n] for r in runs])), lo, hi


def test_nees_of_the_navigation_states_is_consistent_over_five_seeds():
    avg, lo, hi = nees_over_seeds(run_sim)
    print(f"time-averaged NEES over 5 seeds x 60 s: {avg:.2f}, band {lo:.2f}..{hi:.2f}")
    assert lo <= avg <= hi


def test_streaming_and_batch_give_identical_results():
    s = sim.simulate(scenario(DRIVE[:3]), seed=1)
    cfg = nav_config.load_config(None, sim.imu_noise_truth(s.scenario.imu))
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    batch = flt.run(imu, fixes, cfg)
    f = flt.streaming(cfg)
    j, last = 0, None
    for row in imu:
        while j < len(fixes) and fixes[j, 0] <= row[0]:
            x = fixes[j]
            f.push_fix(x[0], x[1:4], x[4:7], x[7], x[8], int(x[9]))
            j += 1
        f.push_imu(row[0], row[1:4], row[4:7])
        last = (f.t, f.r_ecef.copy(), f.q_eb.copy())
    assert last[0] == batch.t[-1]
    assert np.array_equal(last[1], batch.r_ecef[-1])
    assert np.array_equal(last[2], batch.q_eb[-1])
    assert f.counters == batch.counters


def test_a_fix_between_samples_is_applied_at_its_own_time():
    s = sim.simulate(scenario(DRIVE[:3]), seed=2)
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    sol = flt.run(imu, fixes, nav_config.load_config(None, sim.imu_noise_truth(s.scenario.imu)))
    u = sol.updates
    fix_updates = u["t"][(u["kind"] == 1) | (u["kind"] == 2)]
    used = fixes[(fixes[:, 9] == 2) | (fixes[:, 9] == 3)][:, 0]
    # Every fix after the one that initialises the filter is applied exactly at its time,
    # which is not an IMU sampling instant (the simulated IMU does not sample on GPS seconds).
    gap = np.min(np.abs(fix_updates[:, None] - used[None, :]), axis=1)
    assert gap.max() < 1e-9
    after_end = sol.extra["fixes_after_end"]
    assert len(fix_updates) == len(used) - sol.counters["fixes_before_alignment"] - 1 - after_end
    assert np.min(np.abs(imu[:, 0][:, None] - used[None, :]), axis=0).min() > 1e-4


def test_dropped_imu_frames_are_bridged_and_counted():
    s = sim.simulate(scenario(DRIVE[:4]), seed=3)
    imu = sim.imu_table(s)
    keep = np.ones(len(imu), bool)
    keep[[1500, 1501, 1502, 2200]] = False
    sol = flt.run(imu[keep], sim.fix_table(s), nav_config.load_config(None, sim.imu_noise_truth(s.scenario.imu)),
                  covariance=True)
    assert sol.counters["imu_gaps_bridged"] == 2
    assert sol.counters["imu_samples"] == keep.sum()
    err = evaluate.nav_errors(sol, truth_of(s))
    hk = sol.heading_known
    assert np.mean(np.abs(err.e9[hk]) <= 3 * sol.sigma[hk, :9]) > 0.95


def test_increments_that_cover_a_double_step_are_integrated_once():
    """Every tenth sample's increments summed into the next one (one sample over two steps, as
    rates integrated over each interval give): with imu_increments_cover_gaps they are the
    motion over both steps, the run as good as the full one; bridged as a lost frame, they were
    the motion over one step with the previous rates added for the other."""
    s = sim.simulate(scenario(DRIVE[:4]), seed=3)
    imu, fixes, tr = sim.imu_table(s), sim.fix_table(s), truth_of(s)
    merged = imu.copy()
    first = np.arange(100, len(imu) - 1, 10)
    merged[first + 1, 1:] += merged[first, 1:]
    merged = np.delete(merged, first, axis=0)
    # The hard gate, so that the fixes do not mend what the integration got wrong: down-weighted
    # updates (robust_after_rejections) pull the bridged run back (2.30 m, 1.87x), and the test is
    # about the increments.
    cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "robust_after_rejections": 0})

    def h_rms(sol):
        e = evaluate.nav_errors(sol, tr)
        return float(np.sqrt(np.mean(np.sum(e.r_ned[sol.heading_known, :2] ** 2, axis=1))))

    full = h_rms(flt.run(imu, fixes, cfg))
    once_sol = flt.run(merged, fixes, {**cfg, "imu_increments_cover_gaps": True})
    twice_sol = flt.run(merged, fixes, cfg)
    assert once_sol.counters["imu_gaps_bridged"] == 0 and twice_sol.counters["imu_gaps_bridged"] == len(first)
    once, twice = h_rms(once_sol), h_rms(twice_sol)
    print(f"\nH RMS: full {full:.3f} m, double steps integrated once {once:.3f} m, bridged {twice:.3f} m")
    assert once < 1.1 * full + 0.05 and twice > 2 * once


@pytest.mark.parametrize("mutate, message", [
    (lambda imu, fx: imu.__setitem__((40, 3), np.nan), "imu row 40"),
    (lambda imu, fx: imu.__setitem__((41, 0), imu[39, 0]), "imu row 41"),
    (lambda imu, fx: fx.__setitem__((3, 2), np.inf), "fixes row 3"),
])
def test_bad_input_names_the_row(mutate, message):
    s = sim.simulate(scenario(DRIVE[:1]), seed=0)
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    mutate(imu, fixes)
    with pytest.raises(ValueError, match=message):
        flt.run(imu, fixes, "default")


def test_wrong_shapes_and_unknown_config_keys_are_errors():
    with pytest.raises(ValueError, match=r"imu: expected shape \(n, 7\)"):
        flt.run(np.zeros((5, 6)), np.zeros((0, 10)))
    with pytest.raises(nav_config.ConfigError, match="unknown key.*gyro_arw_typo"):
        nav_config.load_config(None, {"gyro_arw_typo": 1.0})
    with pytest.raises(nav_config.ConfigError, match="unknown preset"):
        nav_config.load_config({"preset": "nope"})


def test_report2005_preset_holds_the_reports_tables():
    cfg = nav_config.load_config("report2005")
    c = nav_config.core_config(cfg)
    assert np.allclose(c.fix_sigma_ecef_m, [1.8, 1.4, 2.0])  # Table 7.1
    assert np.allclose(np.degrees(c.attitude_sigma_rad), [5, 5, 7])  # Table 7.2
    assert c.velocity_sigma_mps == 1 and c.position_sigma_m == 10
    assert np.allclose(c.gyro_bias_sigma_rad_per_s, 5e-6) and np.allclose(c.accel_bias_sigma_mps2, 5e-3)
    # Table 7.3: gyro as printed; accelerometer densities times 20. z gyro ~1e-3 (ERRATA).
    assert np.allclose(c.gyro_arw_rad_per_sqrt_s, [1.1167e-3, 1.1023e-3, 9.945e-4])
    assert np.allclose(c.accel_vrw_mps_per_sqrt_s, 20 * np.array([7.888e-3, 6.7713e-3, 9.3595e-3]))
    assert str(c.gyro_bias.model).endswith("constant")


def test_config_round_trips_through_toml():
    cfg = nav_config.load_config(None, {"use_fix_velocity": True, "lever_arm_body_m": [0.5, 0.0, -1.2]})
    again = nav_config.load_config(tomllib.loads(nav_config.to_toml(cfg)))
    a, b = nav_config.core_config(cfg), nav_config.core_config(again)
    for k in ("lever_arm_body_m", "gyro_arw_rad_per_sqrt_s", "attitude_sigma_rad", "gyro_bias_sigma_rad_per_s"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    assert b.use_fix_velocity


def test_imu_noise_turns_into_random_walk_biases_with_the_seed_conversions():
    """[imu_noise] against what the Allan figures mean, computed here without the filter's constants:
    bias instability B is the flat ADEV floor F = sqrt(2 ln 2 / pi) B (IEEE Std 952 flicker); the Gauss-Markov
    x' = -x/T + q w standing for it is sized so that its ADEV peak (seed 000 eq. 10.17, maximised on a grid)
    touches F; over times short against T its variance grows as q^2 t (10.17's Wiener limit), so with the
    rate random walk K the bias walks with density sqrt(K^2 + q^2). The white share of B is the density w
    with which the model's ADEV, w^2 / tau + q^2 tau / 3, just reaches F at its lowest."""
    b_gyro, k_gyro, tau_s = 1e-4, 2e-5, 50.0
    noise = {"gyro_arw_rad_per_sqrt_s": 4.36e-5, "gyro_bias_instability_rad_per_s": b_gyro,
             "gyro_rrw_rad_per_s_sqrt_s": k_gyro, "accel_vrw_mps_per_sqrt_s": 1e-3,
             "accel_bias_instability_mps2": 0.0, "accel_rrw_mps2_per_sqrt_s": 0.0, "bias_tau_s": tau_s}
    c = nav_config.core_config(nav_config.load_config(None, {"imu_noise": noise}))
    floor = math.sqrt(2.0 * math.log(2.0) / math.pi) * b_gyro
    tau = np.logspace(-2, 4, 200001) * tau_s
    x = tau / tau_s
    gm_avar_unit_q = tau_s ** 2 / tau * (1 - (3 - 4 * np.exp(-x) + np.exp(-2 * x)) / (2 * x))  # q = 1
    q = floor / math.sqrt(gm_avar_unit_q.max())
    assert np.allclose(c.gyro_arw_rad_per_sqrt_s, 4.36e-5)  # the sensor's N, as the detectors use it
    assert np.allclose(c.gyro_bias.random_walk_per_sqrt_s, math.hypot(k_gyro, q), rtol=1e-3)
    w = np.asarray(c.gyro_flicker_white_rad_per_sqrt_s)
    lowest = np.sqrt((w[:, None] ** 2 / tau + q ** 2 * tau / 3).min(axis=1))
    assert np.allclose(lowest, floor, rtol=1e-3)
    assert np.allclose(c.accel_flicker_white_mps_per_sqrt_s, 0.0)  # no bias instability, no walk
    assert np.allclose(c.accel_bias.random_walk_per_sqrt_s, 0.0)


def test_gyro_noise_model_covers_the_simulated_bias_instability():
    """The filter's gyro model (white density plus random-walk bias, from the report's Allan
    figures through [imu_noise]) against the Allan deviation of the simulator's gyro errors
    (white noise plus a bias instability built from Gauss-Markov terms with a flat floor, and
    the rate random walk), averaged over four 30-minute units: the model's deviation is at
    least that of the errors at every averaging time from 1 to 64 s. With the white density N^2
    alone (before flicker_white_var) it falls to 0.76-0.84 of it at 8-16 s, where the floor
    shows and the random walk has not reached it: the filter's attitude was over-confident."""
    from gpsins.imu import allan
    from gpsins.sim import imu as sim_imu
    from gpsins.sim.scenario import ImuModel

    m, rate = ImuModel(), 64.0
    n = int(rate * 1800)
    arw = np.array(m.gyro_arw_rad_per_sqrt_s)
    avar = 0.0
    for seed in range(4):
        rng = np.random.default_rng(seed)
        e = sim_imu.draw_errors(m, n, rng)
        r = allan.oadev(e.gyro_bias_drift + rng.normal(size=(n, 3)) * arw * math.sqrt(rate), rate, taus="octave")
        avar = avar + r.adev ** 2 / 4
    noise = {"gyro_arw_rad_per_sqrt_s": list(arw),
             "gyro_bias_instability_rad_per_s": list(m.gyro_bias_instability_rad_per_s),
             "gyro_rrw_rad_per_s_sqrt_s": list(m.gyro_rrw_rad_per_s_sqrt_s)}
    c = nav_config.core_config(nav_config.load_config(None, {"imu_noise": noise}))
    tau = r.tau[:, None]
    white = c.gyro_arw_rad_per_sqrt_s ** 2 + c.gyro_flicker_white_rad_per_sqrt_s ** 2  # the process noise's density
    model = np.sqrt(white / tau + c.gyro_bias.random_walk_per_sqrt_s ** 2 * tau / 3)
    sel = (r.tau >= 1.0) & (r.tau <= 64.0)
    ratio = (model / np.sqrt(avar))[sel]
    print("model / simulated gyro ADEV at", r.tau[sel], np.round(ratio, 2))
    assert ratio.min() >= 0.9, ratio


def test_counters_and_kinds_are_named_from_the_cores_one_list(default_run):
    """The core lists its update kinds, events and counters once (filter_names.hpp); a run's counters are
    exactly those, and every update and event it records is a named kind, named as Python shows it."""
    from gpsins import _core

    _, sol = default_run
    assert list(sol.counters) == [*_core.COUNTER_NAMES, "diverged"]
    assert len(set(_core.COUNTER_NAMES)) == len(_core.COUNTER_NAMES)
    kinds = set(np.unique(sol.updates["kind"]).tolist())
    assert kinds and kinds <= set(_core.UPDATE_KINDS) and flt.UPDATE_KINDS == _core.UPDATE_KINDS
    # The names run.json and the report show for the kinds this drive uses.
    assert {flt.UPDATE_KINDS[k] for k in kinds} >= {"fix_3d", "zero_velocity", "zero_rate"}
    assert flt.EVENT_KINDS[2] == "gnss_reset" and set(flt.EVENT_KINDS) == {1, 2, 3, 4, 5}
