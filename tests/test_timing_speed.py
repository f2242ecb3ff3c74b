"""Time alignment of drives served faster than real time through the pty emulators and the
real logger daemon, as `gpsins run --speed S` records them, against the simulator's own
sampling instants."""

import numpy as np
import pytest

from gpsins.devices import emulate
from gpsins import mainjob, sim, timing
from gpsins.timing import alignment
from gpsins.session import measurements
from gpsins.replay import inputs as replay_inputs
from gpsins.sim.scenario import parse

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}
SEGMENTS = [{"label": "stand", "duration_s": 10, "speed_mps": 0},
            {"label": "drive", "duration_s": 38, "speed_mps": 10, "turn_deg": 90}]


def served(tmp_path, monkeypatch, speed):
    """A short drive recorded at `speed` x real time; the emulators are kept for their bookkeeping."""
    s = sim.simulate(parse({"name": "served", "start": START, "segment": SEGMENTS}), seed=3)
    made = []

    class Kept(emulate.Emulators):
        def __init__(self, *args, **kw):
            super().__init__(*args, **kw)
            made.append(self)

    monkeypatch.setattr(mainjob, "Emulators", Kept)
    session = mainjob.record_drive(s, tmp_path, speed=speed)
    return s, made[0], measurements.decode_session(session)


def true_imu_tow(s, em, dec):
    """The simulator's sampling instant of every recorded IMU frame: the emulator served its
    samples in order from the first, every one in its `sent` list (those before the logger
    asked are marked offline), so the n-th frame that went out intact is sample n of that list."""
    sent = np.flatnonzero([f.fate == "ok" for f in em.imu.sent])
    assert len(sent) == len(dec.imu.stamps)
    assert np.array_equal(dec.imu.counter.astype(int), sent & 0xFF)  # the emulator counts every sample
    m = s.imu_rate_hz // int(dec.imu.rate_hz)
    return s.scenario.start.gps_tow_s + s.imu_t[m - 1::m][sent]


@pytest.mark.parametrize("speed", [4.0, 8.0])
def test_robust_alignment_of_a_drive_served_faster_than_real_time(tmp_path, monkeypatch, speed):
    """At speed S the host's clock runs S times faster than GPS time, so a host-side error of a
    tenth of a millisecond is 0.8 ms of GPS time at 8x. Before the fixes the emulators' bytes came
    S times faster than the line the logger dates them by: ID 23 dated early by their length
    (23-63 ms of GPS time at 8x on the report's drive), IMU frames read together dated back over
    each other (up to 14 ms of system time), the devices started apart; here the robust method was
    23 ms (4x) and 64 ms (8x) off, the report's method 18 and 24 ms."""
    s, em, dec = served(tmp_path, monkeypatch, speed)
    truth = true_imu_tow(s, em, dec)
    # The latencies the main job replays with.
    lat = {"imu_latency_s": replay_inputs.DEFAULT_IMU_LATENCY_S, **mainjob.replay_latencies("superstar2", speed)}
    worst = {}
    for method in timing.METHODS:
        al = alignment.align(dec.gps.tow, dec.gps.stamps, dec.gps.week, dec.imu.stamps, dec.imu.counter,
                             dec.imu.rate_hz, method=method, **lat)
        err = al.imu_t - truth
        worst[method] = float(np.abs(err).max())
        print(f"{speed:g}x {method}: error {1e3 * err[0]:+.2f} -> {1e3 * err[-1]:+.2f} ms, "
              f"max {1e3 * worst[method]:.2f} ms, clock {al.imu_clock_ppm:+.1f} ppm, "
              f"damaged stamps {al.damaged_gps_stamps} GPS / {al.damaged_imu_stamps} IMU")
    assert worst["robust"] < 1e-3
    assert worst["robust"] <= worst["report"]
