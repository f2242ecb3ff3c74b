"""Timed message sources for the device emulators.

A source offers what the two devices could send, each item with its time in
seconds from the start of the run:

- ``gps_messages()``: every Superstar II message the receiver can produce, at
  its highest rates (ID 23 at 10 Hz), in time order; the emulator selects what
  the host requested.
- ``imu_samples(rate_hz, t0)``: IMU samples (increments) from t0 at that rate.

The built-in :class:`StaticSource` is a receiver and IMU standing still; the
simulator's scenario source plugs in through the same two methods.
"""

from __future__ import annotations

import math
import struct
from typing import Iterator

import numpy as np

from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2

from .. import _core
from ..formats.gpstime import SECONDS_PER_WEEK
from ..formats.messages import TimedMessage, TimedSample


class StaticSource:
    """A receiver and IMU at rest: plausible contents, not a physical simulation
    (the simulator provides that). Deterministic for a given seed."""

    def __init__(self, duration_s: float = 60.0, seed: int = 0, lat_deg: float = 59.37, lon_deg: float = 17.95,
                 height_m: float = 30.0, week: int = 1590, tow0_s: float = 345600.0, n_sats: int = 8,
                 leap_s: int = 15):
        self.duration_s = duration_s
        self.seed = seed
        self.llh = np.array([math.radians(lat_deg), math.radians(lon_deg), height_m])
        self.week = week
        self.tow0_s = tow0_s
        self.n_sats = n_sats
        self.leap_s = leap_s

    def gps_messages(self) -> Iterator[TimedMessage]:
        rng = np.random.default_rng(self.seed)
        xyz = _core.geodetic_to_ecef(self.llh)
        prns = sorted(rng.choice(np.arange(1, 33), self.n_sats, replace=False).tolist())
        ranges0 = rng.uniform(20.2e6, 25.0e6, self.n_sats)
        rates = rng.uniform(-800.0, 800.0, self.n_sats)
        locks = {p: 0 for p in prns}
        n_epochs = int(round(self.duration_s * 10))
        for k in range(n_epochs):
            t = k / 10.0
            tow = self.tow0_s + t
            obs = []
            for p, r0, rr in zip(prns, ranges0, rates):
                pr = r0 + rr * t + rng.normal(0.0, 0.75)
                cycles = (r0 + rr * t) / 0.19029367279836487
                obs.append(ss2.Observation(p, 45.0 + 0.25 * (p % 8), ss2.code_phase_from_pseudorange(tow, pr),
                                           ss2.carrier_raw(cycles), locks[p]))
            # Real receivers stamp measurements just under whole milliseconds.
            yield TimedMessage(t, ss2.ID_MEASUREMENTS, ss2.Measurements(tow - 3e-8, obs).encode(), tow)
            if k % 10 == 0:
                yield from self._second_messages(t, tow, xyz, prns, rng)

    def _second_messages(self, t, tow, xyz, prns, rng) -> Iterator[TimedMessage]:
        utc = tow - self.leap_s
        day_s = utc % 86400.0
        llh = self.llh
        yield TimedMessage(t, ss2.ID_NAV_USER, ss2.NavUser(
            int(day_s // 3600), int(day_s % 3600 // 60), day_s % 60, 1, 7, 2010, llh[0] + rng.normal(0, 2e-7),
            llh[1] + rng.normal(0, 4e-7), llh[2] + rng.normal(0, 2.0), 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 4.5, 1.2, 1.8, 2,
            len(prns), 3).encode())
        yield TimedMessage(t, ss2.ID_NAV_ECEF, ss2.NavEcef(tow, self.week, *xyz, 0.0, 0.0, 0.0).encode())
        yield TimedMessage(t, ss2.ID_RECEIVER_STATUS, ss2.ReceiverStatus(self.week).encode())
        if int(t) % 10 == 0:
            yield TimedMessage(t, ss2.ID_LEAP, ss2.LeapSeconds(self.leap_s).encode())
        if int(t) % 30 == 0:
            yield TimedMessage(t, ss2.ID_IONO_UTC, ss2.IonoUtc((1.1e-8, 1.5e-8, -6e-8, -1.2e-7),
                                                               (9.0e4, 1.3e5, -6.5e4, -5.2e5), self.leap_s).encode())
            for p in prns:
                words = [[int(w) for w in rng.integers(0, 1 << 24, 8)] for _ in range(3)]
                yield TimedMessage(t, ss2.ID_EPHEMERIS, ss2.EphemerisWords(p, words).encode())

    def imu_samples(self, rate_hz: int, t0: float = 0.0) -> Iterator[TimedSample]:
        rng = np.random.default_rng([self.seed, rate_hz, int(t0 * 1000)])
        dt = 1.0 / rate_hz
        lat = self.llh[0]
        g = float(_core.normal_gravity(lat, self.llh[2]))
        w = 7.292115e-5
        rate_body = np.array([w * math.cos(lat), 0.0, -w * math.sin(lat)])  # facing north, level
        k0 = int(math.ceil(t0 * rate_hz - 1e-9))
        for k in range(max(k0, 1), int(self.duration_s * rate_hz) + 1):
            dtheta = rate_body * dt + rng.normal(0.0, 2e-4 * math.sqrt(dt), 3)
            dv = np.array([0.0, 0.0, -g]) * dt + rng.normal(0.0, 1e-3 * math.sqrt(dt), 3)
            yield TimedSample(k * dt, bp3010.ImuSample(tuple(dtheta), tuple(dv)))


class SessionSource:
    """A recorded session served again (as gpsfake does for gpsd): each frame at
    its recorded stamp relative to the session's first stamp. The IMU is served
    at its recorded rate whatever rate the host asks for."""

    def __init__(self, directory):
        from ..session import logs

        session = logs.read_session(directory)
        gps = session.sensors.get("gps")
        self._gps_frames = gps.frames() if gps else []
        gps_st = gps.stamps if gps else np.zeros(0)
        self._imu = session.imu() if "imu" in session.sensors else None
        every = np.concatenate([gps_st, self._imu.stamps if self._imu else np.zeros(0)])
        self.t0 = float(every.min()) if len(every) else 0.0
        self.duration_s = float(every.max()) - self.t0 if len(every) else 0.0
        self._gps_t = gps_st - self.t0

    def gps_messages(self) -> Iterator[TimedMessage]:
        for t, frame in zip(self._gps_t, self._gps_frames):
            tow = None
            if frame[1] & 0x7F == ss2.ID_MEASUREMENTS:
                tow = ss2.Measurements.decode(ss2.decode_frame(frame)[1]).epoch_tow_s
            yield TimedMessage(float(t), frame[1] & 0x7F, frame, tow)

    def imu_samples(self, rate_hz: int, t0: float = 0.0) -> Iterator[TimedSample]:
        if self._imu is None:
            return
        imu = self._imu
        t = imu.stamps - self.t0
        dtheta, dv = imu.dtheta_rad, imu.dv_mps
        for k in np.flatnonzero(t >= t0 - 1e-9):
            yield TimedSample(float(t[k]), bp3010.ImuSample(tuple(dtheta[k]), tuple(dv[k]), int(imu.status[k])))


class UbxCaptureSource:
    """A recorded UBX stream (a receiver's capture file, NMEA included) served
    at its own timing, as gpsfake does: each UBX frame and each stretch of other
    bytes at the GPS time of the latest epoch seen (RAWX receiver time, else
    NAV-PVT iTOW), relative to the first. Stretches between frames (NMEA) are
    served as they are, so the file goes out byte for byte."""

    def __init__(self, path):
        from ..formats import ubx as ubx_reader
        from ..formats.common import read_bytes

        data = read_bytes(path)
        frames, _ = ubx_reader.split_frames(data)
        items, pos = [], 0
        t_now = None
        for p, cls, mid, start, length in frames:
            if p > pos:
                items.append((t_now, "other", data[pos:p]))
            if (cls, mid) == (0x02, 0x15) and length >= 16:
                t_now = struct.unpack_from("<d", data, start)[0]
            elif (cls, mid) == (0x01, 0x07) and length >= 4 and t_now is None:
                t_now = struct.unpack_from("<I", data, start)[0] * 1e-3
            items.append((t_now, "ubx", data[p:start + length + 2]))
            pos = start + length + 2
        if pos < len(data):
            items.append((t_now, "other", data[pos:]))
        t = np.array([np.nan if x is None else x for x, _, _ in items], dtype=float)
        first = t[np.isfinite(t)][0] if np.isfinite(t).any() else 0.0
        # A week rollover inside the capture keeps the times increasing.
        t = np.where(np.isfinite(t), t, first) - first
        t = np.where(t < -SECONDS_PER_WEEK / 2, t + SECONDS_PER_WEEK, t)
        self._items = [(float(x), kind, b) for x, (_, kind, b) in zip(np.maximum.accumulate(t), items)]
        self.duration_s = self._items[-1][0] if self._items else 0.0
        self.ubx_frames = [b for _, kind, b in self._items if kind == "ubx"]

    def gps_messages(self) -> Iterator[TimedMessage]:
        for t, kind, b in self._items:
            yield TimedMessage(t, "NMEA" if kind == "other" else (b[2], b[3]), b)

    def imu_samples(self, rate_hz: int, t0: float = 0.0) -> Iterator[TimedSample]:
        return iter(())
