"""The built-in drive profiles against their specifications, the scenario keys that
build them (base, repeat), and the IMU rate option: increments that integrate back
to the truth, and sessions the readers and the time alignment take as they are."""

import numpy as np
import pytest

from gpsins.session import measurements
from gpsins import sim
from gpsins.timing import alignment
from gpsins.sim import scenario
from gpsins.sim import earth, messages, trajectory
from gpsins.sim.scenario import ScenarioError, builtin_names, first_seconds, parse, with_imu_rate
from gpsins.sim.session import write_session
from gpsins_logger import bp3010
from simcheck import increment_errors, reintegration_errors

GRID_HZ = 8.0  # coarse truth grid for checking a profile's kinematics
STOPPED_MPS = 0.05


def coarse_truth(sc):
    """The profile's truth on an 8 Hz grid (the simulator's own truth function, two steps per 4 Hz sample)."""
    return trajectory.truth(sc, 0.25, GRID_HZ / 2, int(sc.duration_s * GRID_HZ / 2) - 1, substeps=2)


def kinematics(sc):
    tr = coarse_truth(sc)
    speed = np.linalg.norm(tr.v_ecef, axis=1)
    a_ned = np.einsum("nji,nj->ni", earth.ecef_to_ned_matrix(tr.lat, tr.lon), tr.a_ecef)
    return tr, speed, np.hypot(a_ned[:, 0], a_ned[:, 1])


def stops(t, speed, min_s=3.0):
    """(start, duration) of every run of at least min_s with the speed under STOPPED_MPS."""
    still = np.concatenate([[0], (speed < STOPPED_MPS).astype(int), [0]])
    d = np.diff(still)
    a, b = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    dur = t[b] - t[a] + 1.0 / GRID_HZ
    return [(float(t[i]), float(x)) for i, x in zip(a, dur) if x >= min_s]


def test_the_profiles_are_built_in():
    assert {"default", "long", "urban_highway", "stop_and_go", "walk"} <= set(builtin_names())


def test_walk_is_pedestrian():
    sc = scenario.load("walk")
    tr, speed, acc = kinematics(sc)
    assert speed.max() <= 1.5 + 1e-9 and acc.max() < 1.5
    moving = speed > STOPPED_MPS
    assert 1.0 <= speed[moving].mean() <= 1.5
    # cruising between the ramps of speed: inside the walking band
    cruise = moving & (np.abs(np.gradient(speed, tr.t)) < 0.02)
    assert speed[cruise].min() >= 0.98 and cruise.sum() > 0.5 * moving.sum()
    # pedestrian stops: a standing start, 3 per loop of 4 loops (5-20 s each), a final stand
    s = stops(tr.t, speed)
    assert s[0][0] == pytest.approx(0.0, abs=0.3) and s[-1][0] + s[-1][1] == pytest.approx(sc.duration_s, abs=0.3)
    middle = s[1:-1]
    assert len(middle) == 12 and all(5.0 <= d <= 20.0 for _, d in middle), middle
    # the walk stays in a town centre: within a kilometre of its start
    r0 = tr.r_ecef[0]
    assert np.linalg.norm(tr.r_ecef - r0, axis=1).max() < 1000.0


def test_stop_and_go_has_many_short_stops():
    sc = scenario.load("stop_and_go")
    tr, speed, acc = kinematics(sc)
    assert speed.max() <= 10.0 + 1e-9 and acc.max() < 3.0
    s = stops(tr.t, speed)
    middle = s[1:-1]  # between the parked start and the end
    # 6-20 s standing, plus the last and first fractions of a second of the ramps under 5 cm/s
    assert len(middle) == 24 and all(6.0 <= d <= 22.5 for _, d in middle), middle
    gaps = np.diff([a for a, _ in middle])
    assert gaps.max() < 60.0  # never more than a minute between stops
    assert 900.0 <= sc.duration_s <= 1000.0


def test_urban_highway_is_an_hour_of_city_and_motorway():
    sc = scenario.load("urban_highway")
    assert sc.duration_s == 3600.0
    tr, speed, acc = kinematics(sc)
    dt = 1.0 / GRID_HZ
    motorway = np.sum(speed >= 25.0) * dt
    urban = np.sum((speed > STOPPED_MPS) & (speed < 15.0)) * dt
    assert 25 * 60 <= motorway <= 40 * 60 and urban >= 15 * 60, (motorway, urban)
    assert len(stops(tr.t, speed)) >= 12
    assert acc.max() < 4.0  # no turn sharper than a car takes
    assert np.degrees(np.abs(tr.ypr[:, 1])).max() <= 4.0 + 1e-9
    # three passes under the overpass, each blocking every satellite
    over = [o for o in sc.obstructions if o.label == "overpass"]
    assert len(over) == 3 and all(o.below_elevation_deg >= 90 and o.t1_s - o.t0_s == 4.0 for o in over)


def test_long_repeats_the_default_drive_twelve_times():
    base, sc = scenario.load("default"), scenario.load("long")
    drive = base.segments[1:-1]  # A-B .. W-X
    span = sum(s.duration_s for s in drive)
    assert sc.duration_s == base.duration_s + 11 * span and 43 * 60 <= sc.duration_s <= 44 * 60
    assert len(sc.obstructions) == 12 * len(base.obstructions)  # all of them lie in the driven span
    assert sc.segments[1 + 5 * len(drive)].label == "A-B #6"
    # every pass drives the same speed and grade profile as the first (the heading turns on), from
    # B-C on: the first pass starts A-B from the level start, the others from W-X's grade
    t = np.arange(base.segments[0].duration_s + drive[0].duration_s, base.segments[0].duration_s + span, 0.1)
    first = trajectory.profiles(sc, t)
    for k in (1, 6, 11):
        again = trajectory.profiles(sc, t + k * span)
        for name in ("speed", "pitch", "speed_dot", "yaw_dot"):
            assert np.allclose(getattr(again, name), getattr(first, name), atol=1e-9), (k, name)
        turn = np.radians(sum(s.turn_deg for s in drive))
        assert np.allclose(again.yaw, first.yaw + k * turn, atol=1e-9)
    # and the obstruction times follow their passes
    o1 = sorted(o.t0_s for o in base.obstructions)
    assert sorted(o.t0_s for o in sc.obstructions)[:len(o1)] == o1
    assert sorted(o.t0_s for o in sc.obstructions)[-len(o1):] == pytest.approx([x + 11 * span for x in o1])


def test_base_and_repeat_keys(tmp_path):
    (tmp_path / "a.toml").write_text('name = "a"\n[imu]\nrate_hz = 32\n[[segment]]\nlabel = "s"\nduration_s = 2\n'
                                     '[[segment]]\nlabel = "x"\nduration_s = 3\nspeed_mps = 4\n'
                                     '[[segment]]\nlabel = "y"\nduration_s = 1\n'
                                     '[[obstruction]]\nsegment = "y"\nazimuth_deg = [0, 90]\n'
                                     'below_elevation_deg = 30\n', encoding="utf-8")
    (tmp_path / "b.toml").write_text('base = "a.toml"\n[imu.terms]\nwhite_noise = false\n'
                                     '[[repeat]]\nfirst = "x"\nlast = "y"\ncount = 3\n', encoding="utf-8")
    sc = scenario.load(tmp_path / "b.toml")
    assert sc.name == "b" and sc.imu.rate_hz == 32 and not sc.imu.terms["white_noise"] and sc.imu.terms["scale_factor"]
    assert [s.label for s in sc.segments] == ["s", "x", "y", "x #2", "y #2", "x #3", "y #3"]
    assert [(o.t0_s, o.t1_s) for o in sc.obstructions] == [(5.0, 6.0), (9.0, 10.0), (13.0, 14.0)]
    segs = [{"label": "s", "duration_s": 2.0}, {"label": "x", "duration_s": 3.0}]
    with pytest.raises(ScenarioError, match="repeat 1: last = 'z' names 0 segments"):
        parse({"segment": segs, "repeat": [{"first": "x", "last": "z", "count": 2}]}, "r.toml")
    with pytest.raises(ScenarioError, match="count must be an integer >= 1"):
        parse({"segment": segs, "repeat": [{"first": "s", "last": "x", "count": 0}]}, "r.toml")
    with pytest.raises(ScenarioError, match="straddles"):
        parse({"segment": segs, "repeat": [{"first": "x", "last": "x", "count": 2}],
               "obstruction": [{"t0_s": 1.0, "t1_s": 3.0, "azimuth_deg": [0, 1], "below_elevation_deg": 5}]}, "r.toml")
    with pytest.raises(ScenarioError, match="takes its segments"):
        parse({"base": "default", "segment": segs}, "r.toml")


def test_imu_rate_option_checks_the_line():
    sc = scenario.load("default")
    with pytest.raises(ScenarioError, match="imu_baud = 38400 cannot carry 400 Hz"):
        parse({"segment": [{"label": "a", "duration_s": 1.0}], "imu": {"rate_hz": 400}}, "x.toml")
    with pytest.raises(ScenarioError, match="rate_hz must be a positive integer"):
        parse({"segment": [{"label": "a", "duration_s": 1.0}], "imu": {"rate_hz": 64.5}}, "x.toml")
    assert with_imu_rate(sc, 200).timing.imu_baud == 38400  # 200 frames/s of 160 bits fit
    assert with_imu_rate(sc, 400).timing.imu_baud == 115200
    assert sc.imu.rate_hz == 64 and sc.timing.imu_baud == 38400  # the original is left alone
    assert [trajectory.substeps_for(r) for r in (50, 64, 100, 200, 400)] == [20, 16, 10, 6, 2]


def _short(name, seconds, rate):
    """The first `seconds` of a built-in profile at an IMU rate."""
    return first_seconds(with_imu_rate(scenario.load(name), rate), seconds)


@pytest.mark.parametrize("rate", [50, 200, 400])
def test_increments_at_other_rates_integrate_back_to_the_truth(rate):
    """Stop-and-go's first block (three stops) at 50, 200 and 400 Hz: the ideal increments
    compose to the truth's attitude and velocity changes; at 400 Hz, whose internal grid is the
    coarsest (800 Hz, two steps per sample), the truth also re-integrates to millimetres."""
    s = sim.simulate(_short("stop_and_go", 150.0, rate), seed=2)
    assert s.imu_rate_hz == rate and np.allclose(np.diff(s.imu_t), 1.0 / rate, rtol=1e-9)
    assert np.array_equal(s.truth.t[s.truth_at_imu], s.imu_t)
    if rate == 400:
        att, pos = reintegration_errors(s.truth)
        assert att < 2e-8 and pos < 2e-3, (att, pos)
    for t0, t1 in ((38.0, 80.0), (80.0, 140.0)):  # pulling away and the first stops; the stop and crawl
        att, vel = increment_errors(s, t0, t1)
        assert att < 1e-12 and vel < 1e-9, (t0, att, vel)
    # the unit's noise scales with the rate as white noise must: per-sample std = ARW sqrt(dt)
    still = (s.imu_t > 5.0) & (s.imu_t < 35.0)
    noise = s.imu_dtheta[still] - s.ideal_dtheta[still] @ s.imu_errors.gyro_matrix.T
    arw = np.asarray(s.scenario.imu.gyro_arw_rad_per_sqrt_s)
    assert np.allclose(noise.std(axis=0), arw / np.sqrt(rate), rtol=0.1)


@pytest.mark.parametrize("rate", [50, 200, 400])
def test_sessions_at_other_rates_decode_and_align(tmp_path, rate):
    """A session at a non-BP3010 rate: the readers take the rate from the sidecar (LSBs, counter)
    and the robust alignment gives every sample its true GPS time."""
    sc = _short("default", 60.0, rate)
    sc.timing.imu_drop_probability = 0.01
    s = sim.simulate(sc, seed=3)
    d = write_session(s, tmp_path / f"s{rate}")
    dec = measurements.decode_session(d)
    assert dec.imu.rate_hz == rate and "imu_frame" in dec.sidecar["simulation"]
    al = alignment.align(dec.gps.tow, dec.gps.stamps, dec.gps.week, dec.imu.stamps, dec.imu.counter, dec.imu.rate_hz,
                         gps_latency_s=messages.MEASUREMENT_DELAY_S)
    k = al.imu_index + int(dec.imu.counter[0]) - 1  # sample number of each kept frame
    assert k[-1] < len(s.imu_t) and len(al.gaps) > 0
    err = al.imu_t - (sc.start.gps_tow_s + s.imu_t[k])
    assert np.abs(err).max() < 1e-3, np.abs(err).max()
    # the decoded increments are the unit's within half an LSB of the rate's frame
    lsb = bp3010.dtheta_lsb_rad(rate)
    assert np.abs(dec.imu.dtheta_rad - s.imu_dtheta[k]).max() <= 0.5 * lsb * (1 + 1e-9)
    assert np.abs(dec.imu.dv_mps - s.imu_dv[k]).max() <= 0.5 * bp3010.dv_lsb_mps(rate) * (1 + 1e-9)


def test_frames_built_at_once_equal_the_codec(tmp_path):
    """The session's vectorised BP3010 encoder gives the codec's bytes, saturation included."""
    from gpsins.sim.session import imu_frames

    rng = np.random.default_rng(4)
    for rate in (8, 64, 200):
        dth = rng.normal(0.0, 0.05, (500, 3)) * 64 / rate
        dv = rng.normal(0.0, 1.0, (500, 3)) * 64 / rate
        dth[7, 1], dv[9, 2], dv[11, 0] = 1.0, -100.0, 2.5 * 64 / rate  # over range
        dth[13] = np.array([0.5, -1.5, 2.5]) * bp3010.dtheta_lsb_rad(rate)  # halves: round to even
        frames = imu_frames(dth, dv, np.arange(500) + 250, rate)
        for k in range(500):
            ref = bp3010.ImuSample(tuple(dth[k]), tuple(dv[k]), counter=(k + 250) & 0xFF).encode(rate)
            assert frames[k].tobytes() == ref, (rate, k)


def test_emulator_source_serves_only_rates_that_divide_the_simulation():
    sc = parse({"segment": [{"label": "a", "duration_s": 2.0}], "imu": {"rate_hz": 128}})
    src = messages.SimSource(sim.simulate(sc, 1))
    served = list(src.imu_samples(64))
    assert len(served) == len(src.sim.imu_t) // 2 and served[0].t == src.sim.imu_t[1]
    with pytest.raises(ValueError, match="cannot be served at 100 Hz"):
        next(iter(src.imu_samples(100)))
