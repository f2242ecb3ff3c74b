"""The filter off the clean path (issue 14): IMU rates other than 64 Hz, gentle stop-and-go,
bad samples, a dead accelerometer, long IMU gaps; and its NEES over a whole drive, the
unknown-heading start included. Truth from the simulator."""


import numpy as np
import pytest

from gpsins import _core, evaluate, sim
from gpsins.nav import runs as flt
from gpsins.replay import solution
from gpsins.nav import config as nav_config
from gpsins.sim import scenario
from gpsins.sim.scenario import first_seconds, parse, with_imu_rate

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}


def stop_and_go(rate_hz: int, stops: int = 3):
    """Stops with gentle pull-aways: a creep from rest to 2 m/s over 15 s, whose first seconds
    an IMU cannot tell from standing (this drove the filter 5-57 km off at 64 and 200 Hz)."""
    seg = [{"label": "stand", "duration_s": 20, "speed_mps": 0},
           {"label": "go", "duration_s": 10, "speed_mps": 10},
           {"label": "turn", "duration_s": 15, "turn_deg": 90}]
    for i in range(stops):
        seg += [{"label": f"stop{i}", "duration_s": 12, "speed_mps": 0},
                {"label": f"wait{i}", "duration_s": 10, "speed_mps": 0},
                {"label": f"creep{i}", "duration_s": 15, "speed_mps": 2.0},
                {"label": f"go{i}", "duration_s": 10, "speed_mps": 8, "turn_deg": 30 * (-1) ** i}]
    seg += [{"label": "end", "duration_s": 15, "speed_mps": 0}]
    return parse({"name": "stop-and-go", "start": START, "segment": seg, "imu": {"rate_hz": rate_hz}})


def truth_of(s):
    tr = s.truth
    return evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb)


def true_speed(s, t):
    i = np.clip(np.searchsorted(s.truth.t, t), 0, len(s.truth.t) - 1)
    return np.linalg.norm(s.truth.v_ecef[i], axis=1)


def final_error(s, sol) -> float:
    return float(np.linalg.norm(evaluate.nav_errors(sol, truth_of(s)).r_ned[-1]))


@pytest.mark.parametrize("rate_hz", [64, 200])
def test_gentle_stop_and_go_converges_at_64_and_200_hz(rate_hz):
    s = sim.simulate(stop_and_go(rate_hz), seed=0)
    sol = flt.run(sim.imu_table(s), sim.fix_table(s), "default")
    v = true_speed(s, sol.t)
    ss = sol.standstill
    false_rate = ss[v > 0.5].mean()
    # At rest for at least a window (0.5 s) plus a block: standing.
    rest = np.convolve(v < 1e-6, np.ones(int(0.6 * rate_hz)), "full")[:len(v)] >= int(0.6 * rate_hz)
    missed = 1.0 - ss[rest].mean()
    err = final_error(s, sol)
    print(f"{rate_hz} Hz: final {err:.2f} m, standstill at > 0.5 m/s {100 * false_rate:.2f} %, "
          f"missed at rest {100 * missed:.1f} %, fixes rejected {sol.counters['fixes_rejected']}")
    assert err < 5.0
    assert false_rate == 0.0
    assert missed < 0.1
    # Left over (issue 14, correlated GNSS errors): standing, the fixes' slowly varying errors
    # make the position over-confident (0.4 m sigma, 2.8 m error at 64 Hz seed 0), and the next
    # creep then costs a few rejected fixes and one GNSS reset before it is explained again.
    assert sol.counters["fixes_rejected"] <= 10 and sol.counters["gnss_resets"] <= 1


@pytest.mark.parametrize("rate_hz, seed", [(64, 1), (200, 2)])
def test_a_slow_walk_takes_its_heading_from_an_accurate_course(rate_hz, seed):
    """The walk profile (1.0-1.5 m/s, never the 3 m/s the vehicle's course needs): its
    heading came from no fix before, the yaw stayed unknown for the whole walk and the
    filter reset onto GNSS 1-3 times. A measured velocity at 0.05 m/s x HDOP gives the
    course to about 3 deg at 1.3 m/s: the heading is set within seconds of setting off
    (at 40 s), within 3 sigma of the truth."""
    s = sim.simulate(first_seconds(with_imu_rate(scenario.load("walk"), rate_hz), 190.0), seed=seed)
    sol = flt.run(sim.imu_table(s), sim.fix_table(s), "default", covariance=True)
    set_at = [e["t"] for e in sol.event_list() if e["kind"] == "heading_set"]
    assert len(set_at) == 1 and 40.0 < set_at[0] < 45.0
    err = evaluate.nav_errors(sol, truth_of(s))
    k = np.searchsorted(sol.t, set_at[0] + 1.0)
    yaw_err = abs(err.ypr_deg[k, 0])
    yaw_sigma = solution.nav_sigmas(sol, sol.llh())[2][k, 2]  # about down
    print(f"{rate_hz} Hz seed {seed}: heading at {set_at[0]:.1f} s, yaw error {yaw_err:.2f} deg "
          f"(sigma {yaw_sigma:.2f}), final {np.linalg.norm(err.r_ned[-1, :2]):.2f} m")
    assert yaw_err < 3.0 * yaw_sigma
    # Nothing the fixes disagree with, no standstill while walking.
    assert sol.counters["fixes_rejected"] == 0 and sol.counters["gnss_resets"] == 0
    assert not (sol.standstill & (true_speed(s, sol.t) > 0.6)).any()
    assert np.linalg.norm(err.r_ned[-1, :2]) < 5.0


@pytest.fixture(scope="module")
def default_drive():
    return sim.simulate(scenario.load("default"), seed=0)


def run_default(s, imu, **over):
    cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), **over})
    return flt.run(imu, sim.fix_table(s), cfg, covariance=True)


def test_a_sample_beyond_the_sensor_range_is_not_integrated(default_drive):
    s = default_drive
    imu = sim.imu_table(s)
    k = np.searchsorted(imu[:, 0], 100.0)
    imu[k, 1] = 1e6  # rad: was 98 km (1.6e9 m here) off
    sol = run_default(s, imu)
    assert sol.counters["imu_samples_rejected"] == 1
    assert [e["kind"] for e in sol.event_list()].count("imu_sample_rejected") == 1
    assert final_error(s, sol) < 5.0 and not sol.counters["diverged"]


def test_a_fix_at_saturated_dop_is_not_used(default_drive):
    """A receiver's DOP of 99.9 means only "at least 99.9": weighted as 99.9, a 3D fix 300 m off
    passed the gate on the simulated motorway (urban_highway seed 0 at 200 Hz) and pulled the filter
    onto the 2D fixes 200 m off after it, 200 m off and reset. Beyond fix_max_dop a fix is not used."""
    s = default_drive
    fixes = sim.fix_table(s)
    k = np.flatnonzero((fixes[:, 0] > 150.0) & (fixes[:, 9] == 2) & (fixes[:, 7] < 3.0))[0]  # a good 3D fix
    fixes[k, 1:4] += 300.0 / np.sqrt(3.0)
    fixes[k, 7:9] = 99.9
    cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "fix_max_dop": 20.0})
    sol = flt.run(sim.imu_table(s), fixes, cfg)
    clean = flt.run(sim.imu_table(s), np.delete(fixes, k, axis=0), cfg)  # without that fix
    assert sol.counters["fixes_dop_masked"] == clean.counters["fixes_dop_masked"] + 1
    unmasked = flt.run(sim.imu_table(s), fixes, {**cfg, "fix_max_dop": 0.0})
    def worst_after(r):  # over the 10 s after the fix
        near = (r.t >= fixes[k, 0]) & (r.t < fixes[k, 0] + 10.0)
        return np.linalg.norm(evaluate.nav_errors(r, truth_of(s)).r_ned[near], axis=1).max()

    worst = {name: worst_after(r) for name, r in (("masked", sol), ("clean", clean), ("unmasked", unmasked))}
    print(worst)
    assert worst["masked"] == pytest.approx(worst["clean"], rel=1e-6)
    assert worst["unmasked"] > worst["masked"] + 1.0


def test_a_fix_at_saturated_dop_sets_no_heading(default_drive):
    """The fix the heading would come from (the first at heading_min_speed_mps), at HDOP 99.9 with
    its velocity turned 90 degrees: it set the heading 90 degrees off before the DOP mask was
    looked at. Masked, it is as if absent."""
    s = default_drive
    fixes = sim.fix_table(s)
    cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "fix_max_dop": 20.0,
                                        "heading_max_course_sigma_deg": 0.0})  # a vehicle's course only
    first = [e["t"] for e in flt.run(sim.imu_table(s), fixes, cfg).event_list() if e["kind"] == "heading_set"][0]
    k = int(np.argmin(np.abs(fixes[:, 0] - first)))
    assert np.all(np.isfinite(fixes[k, 4:7]))
    up = fixes[k, 1:4] / np.linalg.norm(fixes[k, 1:4])
    fixes[k, 4:7] = np.cross(up, fixes[k, 4:7])  # the same speed, 90 degrees to the left
    fixes[k, 7:9] = 99.9
    sol = flt.run(sim.imu_table(s), fixes, cfg)
    clean = flt.run(sim.imu_table(s), np.delete(fixes, k, axis=0), cfg)
    set_at = [e["t"] for e in sol.event_list() if e["kind"] == "heading_set"]
    assert set_at[0] > fixes[k, 0]
    yaw = lambda r: np.abs(evaluate.nav_errors(r, truth_of(s)).ypr_deg[r.heading_known, 0])  # noqa: E731
    np.testing.assert_allclose(yaw(sol), yaw(clean), rtol=1e-6, atol=1e-9)
    assert yaw(sol)[:100].max() < 10.0


def test_ten_seconds_of_zero_delta_v_recovers_through_a_gnss_reset(default_drive):
    s = default_drive
    imu = sim.imu_table(s)
    imu[(imu[:, 0] >= 100) & (imu[:, 0] < 110), 4:7] = 0.0  # was 14-18 km off, half the fixes rejected
    sol = run_default(s, imu)
    c = sol.counters
    assert c["gnss_resets"] >= 1 and c["diverged"]
    resets = [e["t"] for e in sol.event_list() if e["kind"] == "gnss_reset"]
    assert all(100 < t < 125 for t in resets)
    assert c["fixes_rejected"] < 20
    err = evaluate.nav_errors(sol, truth_of(s))
    after = sol.t > 140
    assert np.mean(np.abs(err.e9[after]) <= 3 * sol.sigma[after, :9]) > 0.95
    assert final_error(s, sol) < 5.0


def test_a_long_imu_gap_restarts_the_navigation(default_drive):
    s = default_drive
    imu = sim.imu_table(s)
    keep = ~((imu[:, 0] >= 100) & (imu[:, 0] < 108))  # 8 s unplugged while driving
    sol = run_default(s, imu[keep])
    assert sol.counters["imu_gap_restarts"] == 1
    ev = sol.event_list()
    assert ev[[e["kind"] for e in ev].index("imu_gap_restart")]["value"] == pytest.approx(8.0, abs=0.05)
    err = evaluate.nav_errors(sol, truth_of(s))
    after = sol.t > 118
    assert np.mean(np.abs(err.e9[after]) <= 3 * sol.sigma[after, :9]) > 0.95
    assert final_error(s, sol) < 5.0 and not sol.counters["diverged"]


def with_lever_arm(s, fixes, lever_body_m):
    """The receiver's fixes moved to an antenna at lever_body_m (body axes) from the IMU, by the
    simulator's true attitude at each fix time."""
    out = fixes.copy()
    ok = (out[:, 0] >= s.truth.t[0]) & (out[:, 0] <= s.truth.t[-1]) & np.isfinite(out[:, 1])
    q = truth_of(s).at(out[ok, 0]).q_eb
    out[ok, 1:4] += np.einsum("nij,j->ni", evaluate._dcm(q), np.asarray(lever_body_m))
    return out


LEVER = [1.2, -0.4, -1.5]


def rejected_fix_times(sol) -> np.ndarray:
    u = sol.updates
    return u["t"][~u["accepted"].astype(bool) & np.isin(u["kind"], (1, 2))]


def fixes_far_off(s, fixes, cfg, lever_body_m=None) -> np.ndarray:
    """Times of the fixes whose true horizontal error is beyond 4 times the horizontal RMS of the white
    part the filter gives them (UERE x HDOP): the ones a chi-square gate is right to refuse."""
    ok = np.isin(fixes[:, 9], (2, 3)) & (fixes[:, 0] >= s.truth.t[0]) & (fixes[:, 0] <= s.truth.t[-1])
    f = fixes[ok]
    r_true = s.truth.position_at(f[:, 0])
    if lever_body_m is not None:
        r_true = with_lever_arm(s, np.column_stack([f[:, :1], r_true, f[:, 4:]]), lever_body_m)[:, 1:4]
    h = _ned(f[:, 1:4] - r_true, _core.ecef_to_geodetic(f[:, 1:4]))[:, :2]
    uere = np.where(f[:, 9] == 3, cfg.get("fix_uere_2d_m") or cfg["fix_uere_m"], cfg["fix_uere_m"])
    return f[np.linalg.norm(h, axis=1) > 4.0 * uere * f[:, 7], 0]


def _ned(d_ecef: np.ndarray, llh: np.ndarray) -> np.ndarray:
    lat, lon = llh[:, 0], llh[:, 1]
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    n = -sl * co * d_ecef[:, 0] - sl * so * d_ecef[:, 1] + cl * d_ecef[:, 2]
    e = -so * d_ecef[:, 0] + co * d_ecef[:, 1]
    return np.column_stack([n, e, -(cl * co * d_ecef[:, 0] + cl * so * d_ecef[:, 1] + sl * d_ecef[:, 2])])


@pytest.mark.parametrize("over", [{}, {"use_fix_velocity": True}, {"scale_factor_states": True},
                                  {"lever_arm_body_m": LEVER}],
                         ids=["default", "fix_velocity", "scale_factors", "lever_arm"])
def test_nees_over_the_whole_default_drive_is_inside_its_band(over):
    """From the first output on, standing with the heading unknown and moving off included;
    also with the paths the default drive does not take (was 68 from t = 0; 27.7 with fix
    velocities)."""
    sc = scenario.load("default")
    runs, rms = [], []
    for seed in range(4):
        s = sim.simulate(sc, seed=seed)
        fixes = sim.fix_table(s)
        if "lever_arm_body_m" in over:
            fixes = with_lever_arm(s, fixes, over["lever_arm_body_m"])
        cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), **over})
        sol = flt.run(sim.imu_table(s), fixes, cfg, covariance=True)
        err = evaluate.nav_errors(sol, truth_of(s))
        runs.append(evaluate.nees(err.e9, sol.covariance[:, :9, :9]))
        rms.append(np.sqrt(np.mean(err.r_ned[:, :2] ** 2) * 2))
        # A fix may be refused only when it is truly far off: the 2D fixes that hold a wrong height (seed 2:
        # 180-200 m off at HDOP 17 after a 4-satellite fix 80 m off in height).
        off = fixes_far_off(s, fixes, cfg, over.get("lever_arm_body_m"))
        refused = rejected_fix_times(sol)
        good_refused = sum(not (len(off) and np.min(np.abs(off - t)) < 0.01) for t in refused)
        assert good_refused <= 1  # the gate's 1e-4 on 280 fixes, and a filter not perfectly consistent
        assert sol.counters["updates_rejected"] - len(refused) <= 2
    n = min(map(len, runs))
    avg = np.mean([r[:n] for r in runs], 0).mean()
    lo, hi = evaluate.nees_band(9, len(runs))
    print(f"{over}: whole-run NEES over 4 seeds {avg:.2f}, band {lo:.2f}..{hi:.2f}, H RMS {np.mean(rms):.2f} m")
    assert lo <= avg <= hi


def test_a_lever_arm_left_out_is_seen():
    s = sim.simulate(scenario.load("default"), seed=1)
    fixes = with_lever_arm(s, sim.fix_table(s), LEVER)
    base = nav_config.load_config(None, sim.imu_noise_truth(s.scenario.imu))
    down = {}
    for name, cfg in (("with", {**base, "lever_arm_body_m": LEVER}), ("without", base)):
        sol = flt.run(sim.imu_table(s), fixes, cfg, covariance=True)
        down[name] = evaluate.nav_errors(sol, truth_of(s)).r_ned[sol.heading_known, 2]
        assert sol.n_states == 18  # with the fix-error states
    # The antenna sits 1.5 m above the IMU (the vehicle about level): left out, the solution
    # moves up by about that; the horizontal part averages out over the turns.
    assert np.mean(down["without"] - down["with"]) == pytest.approx(LEVER[2], abs=0.3)


def test_nominal_step_comes_from_the_stamps_not_the_configured_rate():
    s = sim.simulate(stop_and_go(200, stops=1), seed=1)
    imu = sim.imu_table(s)
    ok = flt.run(imu, sim.fix_table(s), "default")
    wrong = flt.run(imu, sim.fix_table(s), nav_config.load_config(None, {"imu_rate_hz": 64.0 * 1.3}))
    assert wrong.counters["imu_gaps_bridged"] == 0
    assert np.allclose(wrong.r_ecef[-1], ok.r_ecef[-1], atol=1e-6)
    f = flt.streaming(nav_config.load_config(None, {"imu_rate_hz": 50.0}))
    for row in imu[:50]:
        f.push_imu(row[0], row[1:4], row[4:7])
    assert f.nominal_step_s == pytest.approx(np.median(np.diff(imu[:50, 0])), rel=1e-9)


def test_the_report_divergence_test_is_selectable():
    cfg = nav_config.core_config(nav_config.load_config(None, {"update_check": "attitude_correction",
                                                               "max_attitude_correction_deg": 2.0}))
    assert str(cfg.update_check).endswith("attitude_correction")
    assert cfg.max_attitude_correction_rad == pytest.approx(np.radians(2.0))
    with pytest.raises(nav_config.ConfigError, match="update_check"):
        nav_config.core_config(nav_config.load_config(None, {"update_check": "sometimes"}))


def test_a_refused_zero_velocity_update_ends_the_standstill():
    """Pulling away smoothly can look quiet to the detector; the gate refusing a zero-velocity
    update is then the evidence of motion: no further zero-velocity update for the hold-off.
    (The built-in stop_and_go, seed 1, 380 s: without the rule the detector went on standing
    at up to 1.4 m/s, and 95 zero-velocity updates in a row were refused.) The at-rest specific
    force test now keeps that standstill from beginning; a wide at-rest shift lets it begin here."""
    s = sim.simulate(scenario.load("stop_and_go"), seed=1)
    cfg = nav_config.load_config("default", {"standstill_accel_shift_mps2": 10.0})
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    end = imu[0, 0] + 380.0
    sol = flt.run(imu[imu[:, 0] < end], fixes[fixes[:, 0] < end], cfg)
    u = sol.updates
    zv = np.asarray(u["kind"]) == 4
    t, ok = np.asarray(u["t"])[zv], np.asarray(u["accepted"])[zv]
    refused = t[~ok]
    assert len(refused) >= 1  # the case happens in this drive
    for tr in refused:
        later = t[(t > tr) & (t < tr + _core.InsConfig().standstill_holdoff_s)]
        assert len(later) == 0, f"zero-velocity updates {later - tr} s after one refused at {tr:.2f}"


def test_no_standstill_begins_while_braking_after_a_gnss_outage():
    """A quiet IMU while braking smoothly looks like rest; the mean specific force still carries
    the deceleration. (The built-in stop_and_go, seed 1: after an 8 s fix outage the filter's
    speed had drifted to zero while the car braked at 0.9 m/s; a standstill began there, then the
    fixes were rejected until a GNSS reset.)"""
    s = sim.simulate(scenario.load("stop_and_go"), seed=1)
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    end = imu[0, 0] + 400.0
    sol = flt.run(imu[imu[:, 0] < end], fixes[fixes[:, 0] < end], "default")
    v = true_speed(s, sol.t)
    assert not np.any(sol.standstill[v > 0.5])
    assert sol.counters["gnss_resets"] == 0
    err = evaluate.nav_errors(sol, truth_of(s)).r_ned
    assert np.max(np.hypot(err[:, 0], err[:, 1])) < 8.0


def test_a_long_imu_gap_costs_no_more_than_its_length(default_drive):
    """60 s without the IMU while the fixes go on (issue 37): before, the queued fixes were used on the
    state of the gap's start, rejected, and reset the filter 7 times onto it (diverged); now those beyond
    max_gap_s are counted and left, the restart coasts through the rest, and once the gap has been over
    as long as it lasted the errors are inside the filter's own 3 sigma again."""
    s = default_drive
    imu = sim.imu_table(s)
    keep = ~((imu[:, 0] >= 100) & (imu[:, 0] < 160))
    sol = run_default(s, imu[keep])
    c = sol.counters
    print(f"60 s gap: resets {c['gnss_resets']}, fixes in the gap left {c['fixes_in_imu_gap']}, "
          f"late {c['fixes_late']}, diverged {c['diverged']}")
    assert c["imu_gap_restarts"] == 1 and c["gnss_resets"] == 0 and not c["diverged"]
    assert c["fixes_in_imu_gap"] > 0
    err = evaluate.nav_errors(sol, truth_of(s))
    after = sol.t > 160 + 60
    inside = np.abs(err.e9[after]) <= 3 * sol.sigma[after, :9]
    print(f"from 220 s: inside 3 sigma {inside.mean(axis=0).round(3)}")
    assert inside.mean() > 0.99
