"""3-D motion in the simulator: roll from banking and coordinated turns, a ride along a
3-D track, and the report's roller coaster (seed 004 section 6.1) against its numbers,
the BP3010's ranges and the truth's own re-integration."""

import numpy as np
import pytest

from gpsins import sim
from gpsins.sim import scenario
from gpsins.sim import scenario as scn
from gpsins.sim import ride
from gpsins.sim import trajectory
from gpsins.sim.session import imu_frames
from gpsins_logger import bp3010
from simcheck import increment_errors, reintegration_errors

G = 9.80665


def _one_lap():
    """The roller coaster with one lap and short rests: the same track and dynamics, 72 s."""
    data, source = scn._read("roller-coaster")
    data["track"].update(laps=1, rest_before_s=5.0, rest_after_s=3.0)
    return scn.parse(data, source)


@pytest.fixture(scope="module")
def lap_sim():
    return sim.simulate(_one_lap(), seed=0)


def test_roller_coaster_matches_the_report():
    """Section 6.1: 480 m of track, pitch to 50 deg, roll to 81 deg, about 60 km/h, 3-4 g,
    11 laps of about 60 s after a 5-minute initialisation; the frame about 100 m x 40 m."""
    sc = scenario.load("roller-coaster")
    tr = sc.track
    assert 450 <= tr.period <= 500
    labels = [s.label for s in sc.segments]
    assert labels[0] == "Initialisation" and sc.segments[0].duration_s == 300.0
    laps = [s.duration_s for s in sc.segments if s.label.startswith("Lap ")]
    assert len(laps) == 11 and all(55.0 <= d <= 65.0 for d in laps), laps
    outline = tr.p(np.linspace(0.0, tr.period, 4001))
    extent = outline.max(0) - outline.min(0)
    assert extent[0] <= 100.0 and extent[1] <= 42.0, extent


def test_roller_coaster_dynamics_and_bp3010_ranges(lap_sim):
    """The truth of one lap: the report's angles, speed and g-level, inside the BP3010's
    +-300 deg/s and +-10 g (spec bp3010.md) so nothing saturates."""
    tr = lap_sim.truth
    ypr = np.degrees(tr.ypr)
    speed_kmh = np.linalg.norm(tr.v_ned, axis=1) * 3.6
    g_level = np.linalg.norm(tr.f_body, axis=1) / G
    assert 45.0 <= np.abs(ypr[:, 1]).max() <= 52.0
    assert 78.0 <= np.abs(ypr[:, 2]).max() <= 82.0
    assert 55.0 <= speed_kmh.max() <= 65.0
    assert 3.0 <= g_level.max() <= 4.0
    assert np.degrees(np.abs(tr.w_ib_body)).max() < 300.0
    assert np.abs(tr.f_body).max() < 10.0 * G
    # The emulated unit's frames (+-458 deg/s, +-13 g) never flag over-range either.
    frames = imu_frames(lap_sim.imu_dtheta, lap_sim.imu_dv, np.arange(len(lap_sim.imu_t)), lap_sim.imu_rate_hz)
    assert not np.any(frames[:, 13] & (bp3010.STATUS_GYRO_OVERRANGE | bp3010.STATUS_ACCEL_OVERRANGE))


def test_roller_coaster_truth_reintegrates(lap_sim):
    """Attitude from the integrated body rates, position from the integrated specific force
    (simcheck's own simple strapdown, 1 kHz) against the truth over a whole lap. The errors
    are the re-integrator's own: they fall 6x when the grid is halved (1.7e-6 -> 2.8e-7 rad)."""
    att, pos = reintegration_errors(lap_sim.truth)
    assert att < 5e-6, att  # rad, over 72 s at up to 190 deg/s
    assert pos < 2e-3, pos  # m
    att, vel = increment_errors(lap_sim, 0.0, lap_sim.imu_t[-1])
    assert att < 1e-12 and vel < 5e-5, (att, vel)


def test_sky_closes_under_the_structure(lap_sim):
    """Open sky at the start point; on the lap the count drops to about a fifth and below."""
    fixes = lap_sim.gnss.fixes
    t = np.array([f.t for f in fixes])
    n = np.array([f.sats for f in fixes])
    at_rest = n[t < 5.0]
    riding = n[(t > 5.0) & (t < 5.0 + 62.0)]
    assert at_rest.min() >= 7
    assert riding.min() <= 0.2 * at_rest.max()
    assert 0.2 <= np.mean(riding <= 2) <= 0.6  # about half of the lap under roofs and steel


def _segments_scenario(extra: str):
    text = f"""
name = "turns"
[start]
heading_deg = 0.0
[[segment]]
label = "go"
duration_s = 10
speed_mps = 15
[[segment]]
label = "turn"
duration_s = 20
turn_deg = 180
{extra}
[[segment]]
label = "out"
duration_s = 10
bank_deg = 0
"""
    import tomllib
    return scn.parse(tomllib.loads(text), "turns")


def test_coordinated_turn_rolls_so_the_lateral_specific_force_vanishes():
    """A coordinated turn banks to atan(v psi' / g): the body's lateral specific force is then
    zero (to the Earth-rate, transport-rate and g0-vs-local-gravity terms), the roll positive
    in a right turn; a flat turn keeps roll zero and feels v psi' sideways."""
    flat = _segments_scenario("")
    coord = _segments_scenario("coordinated = true")
    t = np.linspace(12.0, 28.0, 401)
    for sc, expect_roll in ((flat, False), (coord, True)):
        tr = trajectory.truth(sc, 1.0 / 64.0, 64.0, 40 * 64 - 2)
        k = np.searchsorted(tr.t, t)
        p = trajectory.profiles(sc, tr.t[k])
        lateral_acc = p.speed * p.yaw_dot
        roll = tr.ypr[k, 2]
        if expect_roll:
            assert np.allclose(roll, np.arctan(lateral_acc / G), atol=1e-12)
            assert np.degrees(roll.max()) > 20.0  # 15 m/s, 180 deg in 20 s: 4.4 m/s^2 at the peak
            assert np.abs(tr.f_body[k, 1]).max() < 0.02 * np.abs(lateral_acc).max()
        else:
            assert np.all(roll == 0.0)
            assert np.allclose(-tr.f_body[k, 1], -lateral_acc, rtol=0.02, atol=0.05)
        att, pos = reintegration_errors(tr)
        assert att < 1e-7 and pos < 2e-3, (att, pos)


def test_banked_segment_ramps_roll_with_its_rate():
    sc = _segments_scenario("bank_deg = 20")
    tr = trajectory.truth(sc, 1.0 / 64.0, 64.0, 40 * 64 - 2)
    roll = np.degrees(tr.ypr[:, 2])
    assert roll[tr.t < 10.0].max() == 0.0
    assert abs(roll[np.searchsorted(tr.t, 30.0)] - 20.0) < 1e-9
    assert abs(roll[-1]) < 1e-4  # the last sample is just short of the end of the ramp
    att, pos = reintegration_errors(tr)
    assert att < 1e-7 and pos < 2e-3, (att, pos)


def test_track_errors_name_the_key():
    data, source = scn._read("roller-coaster")
    data["track"]["points"] = data["track"]["points"][:3]
    with pytest.raises(scn.ScenarioError, match=r"\[track\]: points"):
        scn.parse(data, source)
    data, source = scn._read("roller-coaster")
    data["track"]["speeds"] = 1
    with pytest.raises(scn.ScenarioError, match="speeds"):
        scn.parse(data, source)
    data, source = scn._read("roller-coaster")
    data["segment"] = [{"label": "x", "duration_s": 1}]
    with pytest.raises(scn.ScenarioError, match="has no"):
        scn.parse(data, source)


def test_loose_and_tight_filters_ride_three_laps_without_diverging():
    """Both couplings through 3 laps (after 60 s at rest) of the roller coaster: no divergence, and on every
    lap the position no worse than the receiver's own fixes, at their epochs (both against the truth, in
    numpy): integrating the IMU with them must not lose what GNSS alone gives. Figures for the full 11 laps
    are in the issue's report."""
    from gpsins import evaluate
    from gpsins.nav import runs as flt
    from gpsins.nav import config as nav_config

    data, source = scn._read("roller-coaster")
    data["track"].update(laps=3, rest_before_s=60.0, rest_after_s=10.0)
    s = sim.simulate(scn.parse(data, source), seed=0)
    tr = s.truth
    truth = evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb)
    tight = sim.tight_inputs(s)
    fixes = sim.fix_table(s)
    fix_err_m = np.linalg.norm(fixes[:, 1:4] - tr.position_at(fixes[:, 0]), axis=1)
    for mode, extra in (("loose", {}), ("tight", tight)):
        cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "mode": mode})
        sol = flt.run(sim.imu_table(s), fixes, cfg, **extra)
        assert not sol.counters["diverged"], mode
        assert sol.t[-1] > s.scenario.duration_s - 1.0
        err_m = np.linalg.norm(evaluate.nav_errors(sol, truth).dr, axis=1)
        for label, a, b in s.scenario.segment_times():
            if not label.startswith("Lap"):
                continue
            f = (fixes[:, 0] >= a) & (fixes[:, 0] < b) & (fixes[:, 9] >= 2)  # 2-D and 3-D fixes
            k = np.searchsorted(sol.t, fixes[f, 0]).clip(0, len(sol.t) - 1)
            rms_sol, rms_fix = np.sqrt(np.mean(err_m[k] ** 2)), np.sqrt(np.mean(fix_err_m[f] ** 2))
            print(f"{mode} {label}: 3-D RMS at the {f.sum()} fixes {rms_sol:.2f} m, the fixes' own {rms_fix:.2f} m")
            # Measured: loose 7.93 / 5.44 / 3.94 m, tight 4.24 / 3.77 / 1.39 m; the fixes 8.42 / 6.32 / 5.66 m.
            assert rms_sol <= rms_fix, (mode, label, rms_sol, rms_fix)


@pytest.fixture(scope="module")
def station_ride():
    """Two laps after the 5-minute initialisation at the station, seed 0."""
    data, source = scn._read("roller-coaster")
    data["track"].update(laps=2, rest_before_s=300.0, rest_after_s=10.0)
    return sim.simulate(scn.parse(data, source), seed=0)


@pytest.mark.parametrize("mode", [
    "loose",
    pytest.param("tight", marks=pytest.mark.xfail(strict=True, reason=(
        "with the GNSS errors measured at the station the tight laps' NEES is 5.94, below its chi-square "
        "band 5.97..12.64 (chi2(9 n) / n, n = 124 s of laps / 20 s multipath = 6.2): under-confident; "
        "loose 8.8 is inside"))),
])
def test_gnss_errors_measured_at_the_station_make_both_filters_consistent(station_ride, mode):
    """Under the steel structure the fixes' errors are multipath, metres and correlated over
    seconds: taken as white, or with the preset's open-sky sizes, the 300 fixes at the station are
    averaged as if nearly independent and both filters are too confident on the laps. Modelled from
    the fixes' scatter at the station (gpsins.fix_scatter, no truth used), the laps' NEES of the 9
    navigation states comes near its expectation of 9, inside its chi-square band (seed 0: white 37 loose /
    49 tight; preset 23.0 / 11.9; measured 8.8 / 5.9, band 5.97..12.64). Doppler is left out
    (doppler_sigma_mps = 0): the station at rest cannot measure its errors on the ride, where the simulator's
    Doppler (the carrier's central difference over 0.2 s) carries the track's jerk, about 0.2 m/s and
    correlated over each element: with it at the preset's 0.1 m/s the tight laps' NEES is 13.8 (attitude,
    velocity and position alike over-confident), at 0.3 m/s 8.3."""
    from scipy.stats import chi2

    from gpsins import evaluate
    from gpsins.nav import fix_scatter
    from gpsins.nav import runs as flt
    from gpsins.nav import config as nav_config

    s = station_ride
    tr = s.truth
    truth = evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb)
    extra = sim.tight_inputs(s) if mode == "tight" else {}
    fixes = sim.fix_table(s)
    segments = s.scenario.segment_times()
    est = fix_scatter.measure(fixes, segments[0][1] + 5.0, segments[0][2])
    # The band: the laps' errors follow the structure's multipath, correlated as exp(-t / tau) (the
    # simulator's multipath_tau_s); their squares as exp(-2 t / tau), so the NEES's mean over T varies as that
    # of T / tau independent epochs, and the average of those 9-dof values is chi2(9 n) / n, 95 % two-sided.
    laps_s = sum(b - a for label, a, b in segments if label.startswith("Lap"))
    n_independent = laps_s / s.scenario.gnss.multipath_tau_s
    lo, hi = chi2.ppf([0.025, 0.975], 9 * n_independent) / n_independent
    nees = {}
    for name, over in (("preset", {}), ("measured", fix_scatter.filter_overrides(est, mode))):
        cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "mode": mode,
                                            "doppler_sigma_mps": 0.0, **over})
        sol = flt.run(sim.imu_table(s), fixes, cfg, covariance=True, **extra)
        assert not sol.counters["diverged"], (mode, name)
        err = evaluate.nav_errors(sol, truth)
        m = np.any([(sol.t >= a) & (sol.t < b) for label, a, b in segments if label.startswith("Lap")], axis=0)
        nees[name] = float(evaluate.nees(err.e9[m], sol.covariance[m][:, :9, :9]).mean())
    print(f"{mode}: laps' NEES preset {nees['preset']:.2f}, measured {nees['measured']:.2f}, "
          f"band {lo:.2f}..{hi:.2f} ({n_independent:.1f} independent samples)")
    # The preset's GNSS errors are sized for the open sky (loose white fixes; tight with the ordinary
    # receiver's 0.6 m multipath): under the steel structure loose is over-confident, above the band
    # (measured 23.0 against 8.8). Tight is more confident than with the measured errors (11.9 against
    # 5.9) but inside the band since its IMU noise covers the bias instability (was above 12).
    assert nees["preset"] > 1.5 * nees["measured"], (mode, nees)
    assert mode == "tight" or nees["preset"] > hi, (mode, nees)
    assert lo <= nees["measured"] <= hi, (mode, nees)


def _riding(pitch_deg=0.3, roll_deg=0.2):
    sc = _segments_scenario("")
    sc.ride = ride.RideModel(pitch_deg=pitch_deg, roll_deg=roll_deg, band_hz=(1.0, 2.0), reference_speed_mps=8.0)
    return sc


def test_ride_rocks_the_body_not_its_path():
    """[ride]: the body pitches and rolls on its suspension at 1-2 Hz, by the stated RMS times
    v^2 / (v^2 + v_ref^2), not at rest; the path is the same as without it, so the body's own
    vertical velocity (what a non-holonomic constraint takes as zero) is speed x the pitch; the
    rates are the angles' derivatives (the truth re-integrates)."""
    still, sc = _segments_scenario(""), _riding()
    tr = trajectory.truth(sc, 1.0 / 64.0, 64.0, 40 * 64 - 2)
    ref = trajectory.truth(still, 1.0 / 64.0, 64.0, 40 * 64 - 2)
    assert np.array_equal(tr.r_ecef, ref.r_ecef) and np.array_equal(tr.v_ecef, ref.v_ecef)
    d_pitch, d_roll = tr.ypr[:, 1] - ref.ypr[:, 1], tr.ypr[:, 2] - ref.ypr[:, 2]
    assert np.all(d_pitch[tr.t <= 0.0] == 0.0)
    cruise = (tr.t > 2.0) & (tr.t < 10.0)  # 15 m/s only from 10 s: the envelope of the speed then
    fast = (tr.t > 12.0) & (tr.t < 40.0)
    k = 15.0 ** 2 / (15.0 ** 2 + 8.0 ** 2)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    assert rms(d_pitch[fast]) == pytest.approx(k * np.radians(0.3), rel=0.15)
    assert rms(d_roll[fast]) == pytest.approx(k * np.radians(0.2), rel=0.15)
    assert rms(d_pitch[cruise]) < rms(d_pitch[fast])
    # Frequency: zero crossings of a 1-2 Hz sum about 3 per second.
    crossings = np.count_nonzero(np.diff(np.sign(d_pitch[fast]))) / 28.0
    assert 2.0 < crossings < 4.5, crossings
    v_body = np.einsum("nji,nj->ni", tr.c_eb, tr.v_ecef)
    speed = np.linalg.norm(tr.v_ecef, axis=1)
    # nose up: "down" in the body
    np.testing.assert_allclose(v_body[fast, 2], speed[fast] * np.sin(d_pitch[fast]), atol=2e-3)
    att, pos = reintegration_errors(tr)
    assert att < 1e-7 and pos < 2e-3, (att, pos)


def test_ride_errors_name_the_key():
    import tomllib
    text = "[[segment]]\nlabel = 'a'\nduration_s = 5\n[ride]\npitch_deg = 0.3\n"
    assert scn.parse(tomllib.loads(text), "r").ride.pitch_deg == 0.3
    with pytest.raises(scn.ScenarioError, match=r"r: \[ride\]: unknown key\(s\) pitch\b"):
        scn.parse(tomllib.loads(text.replace("pitch_deg", "pitch")), "r")
    with pytest.raises(scn.ScenarioError, match=r"\[ride\]: band_hz"):
        scn.parse(tomllib.loads(text + "band_hz = [2.0, 1.0]\n"), "r")
