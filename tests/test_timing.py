"""Time alignment against the simulator's true sampling times: the stamp model's
jitter, host stalls, latencies known to the configuration, IMU clock drift,
dropped frames and realtime clock steps."""

import numpy as np
import pytest

from gpsins.session import measurements
from gpsins import sim, timing
from gpsins.timing import alignment
from gpsins.timing import envelope
from gpsins.timing import clock as timing_clock
from gpsins.sim import messages
from gpsins.sim.scenario import parse
from gpsins.sim.session import realtime, write_session

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}
SEGMENTS = [{"label": "stand", "duration_s": 10, "speed_mps": 0},
            {"label": "drive", "duration_s": 50, "speed_mps": 10, "turn_deg": 90}]
GPS_LAT, IMU_LAT = 0.004, 0.002


def session(tmp_path, name, **timing_opts):
    sc = parse({"name": name, "start": START, "segment": SEGMENTS,
                "timing": {"gps_latency_s": GPS_LAT, "imu_latency_s": IMU_LAT, **timing_opts}})
    s = sim.simulate(sc, seed=5)
    d = tmp_path / name
    write_session(s, d)
    return s, measurements.decode_session(d)


def true_imu_tow(s, dec):
    """The true GPS time of every IMU record (by counter, disambiguated with the known clock)."""
    sc = s.scenario
    approx_t = dec.imu.stamps - IMU_LAT - (realtime(s, 0.0) - 0.0)
    if sc.timing.clock_step_at_s is not None:
        approx_t = approx_t - np.where(approx_t >= sc.timing.clock_step_at_s, sc.timing.clock_step_s, 0.0)
    k_approx = np.round(approx_t * s.imu_rate_hz).astype(int) - 1
    k = k_approx + ((dec.imu.counter.astype(int) - 1 - k_approx) % 256 + 128) % 256 - 128
    return sc.start.gps_tow_s + s.imu_t[k]


def errors(s, dec, method):
    al = alignment.align(dec.gps.tow, dec.gps.stamps, dec.gps.week, dec.imu.stamps, dec.imu.counter, s.imu_rate_hz,
                         method=method, gps_latency_s=GPS_LAT + messages.MEASUREMENT_DELAY_S, imu_latency_s=IMU_LAT)
    return al, al.imu_t - true_imu_tow(s, dec)


CASES = {
    "jitter": {"jitter_mean_s": 0.002},
    "drift_and_drops": {"jitter_mean_s": 0.0005, "imu_clock_ppm": 40.0, "imu_drop_probability": 0.01},
    "clock_step": {"jitter_mean_s": 0.0005, "imu_clock_ppm": -25.0, "clock_step_at_s": 27.3, "clock_step_s": 0.75},
    "step_back": {"jitter_mean_s": 0.001, "imu_drop_probability": 0.005, "clock_step_at_s": 41.0,
                  "clock_step_s": -1.5},
    # 256 frames at 64 Hz: the IMU stamps alone cannot tell this step from a gap.
    "step_of_counter_period": {"jitter_mean_s": 0.0005, "imu_clock_ppm": 30.0, "clock_step_at_s": 27.3,
                               "clock_step_s": 4.0},
    "loaded_host": {"jitter_mean_s": 0.001, "load_stall_rate_hz": 1.0, "load_stall_mean_s": 0.3,
                    "imu_drop_probability": 0.01},
    # The GPS port first read 2.5 s in: the first blocks' stamps lie up to 2.5 s above their floor, as
    # if the clock had been set back then, but no stamp ran back.
    "gps_held_at_start": {"jitter_mean_s": 0.001, "gps_setup_hold_s": 2.5},
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_robust_alignment_is_better_than_a_millisecond(tmp_path, case):
    s, dec = session(tmp_path, case, **CASES[case])
    al, err = errors(s, dec, "robust")
    rms = float(np.sqrt(np.mean(err ** 2)))
    _, err_report = errors(s, dec, "report")
    print(f"{case}: robust RMS {1e3 * rms:.3f} ms, max {1e3 * np.abs(err).max():.3f} ms; report method RMS "
          f"{1e3 * np.sqrt(np.mean(err_report ** 2)):.1f} ms, max {1e3 * np.abs(err_report).max():.1f} ms; "
          f"{al.summary()['imu_frames_missing']} frames missing, clock {al.imu_clock_ppm:+.1f} ppm, "
          f"steps {al.steps_s}")
    assert rms < 1e-3
    ppm = CASES[case].get("imu_clock_ppm", 0.0)
    assert abs(al.imu_clock_ppm - ppm) < 2.0
    if "clock_step_s" in CASES[case]:
        assert len(al.steps_s) == 1 and abs(al.steps_s[0] - CASES[case]["clock_step_s"]) < 2e-3
    else:
        assert al.steps_s == []
    dropped = dec.sidecar["counts"]["imu"].get("frames_dropped_by_simulation", 0)
    assert al.summary()["imu_frames_missing"] == dropped


def test_report_method_error_grows_with_every_dropped_frame(tmp_path):
    s, dec = session(tmp_path, "drops", imu_drop_probability=0.02)
    al, err = errors(s, dec, "report")
    assert al.method == "report"
    # Frames missing between consecutive records (two drops in a row leave a gap of three periods).
    dropped_before = np.cumsum(np.concatenate([[0], np.round(np.diff(true_imu_tow(s, dec)) * 64) - 1]))
    # Each drop moves every later sample 1/64 s early, on top of the start error.
    resid = err + dropped_before / 64.0
    assert np.ptp(resid) < 0.01
    assert np.abs(err[-1]) > 0.1


def test_lower_envelope_is_the_linear_programme_optimum():
    from scipy.optimize import linprog
    rng = np.random.default_rng(1)
    x = np.sort(rng.uniform(0, 100, 400))
    y = 3.0 + 0.01 * x + rng.exponential(0.002, 400)
    a, b = envelope.lower_envelope(x, y)
    lp = linprog([-len(x), -x.sum()], A_ub=np.column_stack([np.ones_like(x), x]), b_ub=y, bounds=[(None, None)] * 2)
    assert np.all(y - (a + b * x) >= -1e-12)
    assert np.isclose(a, lp.x[0], atol=1e-9) and np.isclose(b, lp.x[1], atol=1e-11)


def test_steps_ignore_a_rate_and_lone_damaged_values():
    """The step finder sees a lasting change of the floor, not a slope, a delayed run or one damaged value."""
    rng = np.random.default_rng(3)
    x = np.arange(600) * 0.1
    y = rng.exponential(0.002, 600)
    y[200:212] += np.linspace(0.4, 0.0, 12)  # a 0.4 s host stall
    y[300] -= 0.3  # a damaged stamp
    y[450:] -= 4.0  # a backward step of a whole counter period
    # System time at half the rate of GPS time (served at 2x).
    clock = timing_clock.fit_gps_clock(x, 1000.0 + 0.5 * x + y, 0.0)
    assert list(clock.starts) == [0, 450] and np.allclose(clock.rate, 0.5, atol=1e-4)
    assert clock.damaged.sum() == 1 and clock.damaged[300]
    assert abs(clock.steps_s[0] + 4.0) < 0.01
    assert list(timing_clock._steps(np.delete(y, 300), 0.01)[0]) == [449]


def test_imu_stamps_that_share_no_span_with_the_gps_stamps_are_refused():
    k = np.arange(600)
    gps_tow, gps_stamps = 100.0 + 0.1 * k, 1.7e9 + 0.1 * k
    n = np.arange(3840)
    imu_stamps = 1.7e9 - 3600.0 + n / 64.0
    with pytest.raises(timing.AlignmentError, match="do not overlap"):
        alignment.align(gps_tow, gps_stamps, 1590, imu_stamps, n % 256, 64.0)


def test_numpy_window_minimum_and_lower_hull_equal_scipys():
    """The alignment's running minimum and lower hull (NumPy, so that replay does not import
    scipy.ndimage and scipy.spatial) against scipy's own."""
    from scipy.ndimage import minimum_filter1d
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(5)
    for n in (1, 2, 17, 1000):
        for w in (1, 3, 31, 2000):
            y = rng.normal(size=n)
            ww = max(1, min(w, n))
            pad = np.full(ww, np.inf)
            r = minimum_filter1d(np.concatenate([pad, y, pad]), size=ww, mode="constant", cval=np.inf,
                                 origin=-(ww // 2))
            left, right = envelope.running_min(y, w)
            np.testing.assert_array_equal(left, r[:n])
            np.testing.assert_array_equal(right, r[ww:ww + n])
    for trial in range(60):
        n = int(rng.integers(3, 2000))
        x = np.sort(rng.uniform(0, 100, n)) if trial % 2 else np.arange(n) / 64.0
        y = 0.01 * x + rng.exponential(0.003, n) + (rng.random(n) < 0.01) * 5.0
        xs, ys = (x - x.mean()) / np.ptp(x), y - y.min()
        hull = set(ConvexHull(np.column_stack([xs, ys])).vertices.tolist())
        chain = envelope._lower_chain(x, y)
        assert set(chain.tolist()) <= hull
        assert np.all(np.diff(x[chain]) > 0)
        # Every point lies on or above each edge of the chain's span.
        for a, b in zip(chain[:-1], chain[1:]):
            inside = (x >= x[a]) & (x <= x[b])
            line = y[a] + (y[b] - y[a]) * (x[inside] - x[a]) / (x[b] - x[a])
            assert np.all(y[inside] >= line - 1e-9)


def test_block_by_block_stamp_statistics_equal_the_whole_series(monkeypatch):
    """The damaged-stamp test and the median slope give, block by block (small blocks here), what
    they give over the whole series in one block: a day's stamps are worked through in blocks."""
    rng = np.random.default_rng(4)
    n = 5000
    x = np.cumsum(rng.integers(1, 3, n)).astype(float)
    y = x / 64.0 + rng.exponential(0.003, n)
    y[rng.integers(0, n, 8)] -= 0.5  # damaged stamps
    y[n // 2:] += 3.0  # a clock step
    direct = np.median([(y[j] - y[i]) / (x[j] - x[i]) for i in range(n)
                        for j in [np.searchsorted(x, x[i] + 40.0)] if j < n])
    stamps = y - x / 64.0  # as align gives it: the counter's trend removed
    whole = [envelope.damaged_low(stamps, w, 0.02) for w in (8, 64)]
    monkeypatch.setattr(envelope, "DAMAGE_BLOCK", 97)
    monkeypatch.setattr(envelope, "SLOPE_BLOCK", 97)
    assert envelope.median_slope(x, y, 40.0) == direct
    for w, expected in zip((8, 64), whole):
        got = envelope.damaged_low(stamps, w, 0.02)
        assert np.array_equal(got, expected) and 4 <= got.sum() <= 8
