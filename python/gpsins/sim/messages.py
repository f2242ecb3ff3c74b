"""What the simulated devices send: Superstar II messages with their emission
times, and BP3010 samples. A :class:`SimSource` serves both to the pty
emulators through the same interface as the built-in static source."""

from __future__ import annotations

import math
from typing import Iterator

import numpy as np
from scipy.spatial.transform import Rotation

from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2

from ..formats.messages import TimedMessage, TimedSample
from . import ephemeris
from .gnss import GnssSim
from ..formats.gpstime import SECONDS_PER_WEEK

# Processing delays after the measurement epoch (true time) before the receiver starts sending.
MEASUREMENT_DELAY_S = 0.020
FIX_DELAY_S = 0.060
EPHEMERIS_PERIOD_S = 30.0
IONO_PERIOD_S = 30.0
LEAP_PERIOD_S = 10.0
GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "us")


def _utc_fields(week: int, tow: float, leap: int):
    t = GPS_EPOCH + np.timedelta64(int(round((week * SECONDS_PER_WEEK + tow - leap) * 1e6)), "us")
    day = t.astype("datetime64[D]")
    ymd = str(day).split("-")
    sec_of_day = (t - day) / np.timedelta64(1, "s")
    return (int(sec_of_day // 3600), int(sec_of_day % 3600 // 60), float(sec_of_day % 60), int(ymd[2]),
            int(ymd[1]), int(ymd[0]))


class GpsMessages:
    """The receiver's messages for consecutive blocks of epochs (``GnssSim``), in emission order. The
    ephemeris schedule (all tracked satellites every 30 s, a newly tracked one at once) carries over."""

    def __init__(self, leap_s: int):
        self.leap_s = leap_s
        self._sent_eph: dict[int, float] = {}  # prn -> toe of the ephemeris last sent
        self._last_eph_t = -math.inf
        self._held: list[TimedMessage] = []  # fix messages that a later block's measurements may precede

    def __call__(self, g: GnssSim, last: bool = True) -> list[TimedMessage]:
        """The messages of block g that no later block's can precede (all that remain if last)."""
        leap_s, out = self.leap_s, []
        for k in range(len(g.t)):
            obs = []
            for j in np.flatnonzero(g.tracked[k]):
                obs.append(ss2.Observation(int(j + 1), float(g.cn0_dbhz[k, j]),
                                           ss2.code_phase_from_pseudorange(g.tow_rx[k], g.pseudorange_m[k, j]),
                                           ss2.carrier_raw(g.carrier_cycles[k, j]), int(g.lock_count[k, j])))
            # The receiver stamps measurements just under the epoch (as real logs show).
            out.append(TimedMessage(float(g.t[k]) + MEASUREMENT_DELAY_S, ss2.ID_MEASUREMENTS,
                                    ss2.Measurements(float(g.tow_rx[k]) - 3e-8, obs).encode(), float(g.tow_rx[k])))
        out_fixes: list[TimedMessage] = []
        for f in g.fixes:
            t = f.t + FIX_DELAY_S
            week = g.week
            hh, mm, ss, dd, mo, yy = _utc_fields(week, f.tow_s, leap_s)
            if f.mode:
                vn, ve, vd = f.v_ned
                nav = ss2.NavUser(hh, mm, ss, dd, mo, yy, f.llh[0], f.llh[1], f.llh[2], float(math.hypot(vn, ve)),
                                  float(math.atan2(ve, vn) % (2 * math.pi)), float(vn), float(ve), float(-vd),
                                  2.0 * f.hdop, 2.0 * f.vdop, f.hdop, f.vdop, f.mode, f.sats, 3)
                ecef = ss2.NavEcef(f.tow_s, week, *map(float, f.r_ecef), *map(float, f.v_ecef))
            else:
                nav = ss2.NavUser(hh, mm, ss, dd, mo, yy, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 999.0, 999.0, 99.9,
                                  99.9, 0, f.sats, 2)
                ecef = ss2.NavEcef(f.tow_s, week, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            out_fixes.append(TimedMessage(t, ss2.ID_NAV_USER, nav.encode()))
            out_fixes.append(TimedMessage(t, ss2.ID_NAV_ECEF, ecef.encode()))
            out_fixes.append(TimedMessage(t, ss2.ID_RECEIVER_STATUS, ss2.ReceiverStatus(week).encode()))
            whole = round(f.tow_s)
            if whole % LEAP_PERIOD_S == 0:
                out_fixes.append(TimedMessage(t, ss2.ID_LEAP, ss2.LeapSeconds(leap_s).encode()))
            if whole % IONO_PERIOD_S == 0:
                out_fixes.append(TimedMessage(t, ss2.ID_IONO_UTC, ss2.IonoUtc(tuple(g.ion_alpha), tuple(g.ion_beta),
                                                                        leap_s).encode()))
            # Ephemerides: all tracked satellites every 30 s, a newly tracked one or a new upload at once.
            due = f.t - self._last_eph_t >= EPHEMERIS_PERIOD_S
            k = int(np.searchsorted(g.t, f.t))
            for prn in f.prns:
                toe = float(g.eph_toe[k, prn - 1])
                if due or self._sent_eph.get(prn) != toe:
                    words = ephemeris.encode_subframes(g.eph_table[(prn, toe)])
                    out_fixes.append(TimedMessage(t, ss2.ID_EPHEMERIS, ss2.EphemerisWords(prn, words).encode()))
                    self._sent_eph[prn] = toe
            if due:
                self._last_eph_t = f.t
        # In the whole run's order: measurements, then fix messages, stably sorted by time (same-time messages
        # keep their order). Fix messages come 60 ms after their epoch, so at receiver rates above 25 Hz the
        # next block's first measurements may precede them: those wait for it.
        out = sorted(out + self._held + out_fixes, key=lambda m: m.t)
        if last:
            self._held = []
            return out
        if not len(g.t):
            self._held = out
            return []
        final = float(g.t[-1]) + MEASUREMENT_DELAY_S  # no later message comes before this block's last measurement
        self._held = [m for m in out if m.t > final]
        return [m for m in out if m.t <= final]


def gps_messages(g: GnssSim, leap_s: int) -> list[TimedMessage]:
    """Every message of a whole run's epochs."""
    return GpsMessages(leap_s)(g)


def combine_increments(dtheta: np.ndarray, dv: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact increments over m consecutive intervals (for a host asking for a lower rate)."""
    n = len(dtheta) // m
    dth = dtheta[:n * m].reshape(n, m, 3)
    dvv = dv[:n * m].reshape(n, m, 3)
    rot = Rotation.from_rotvec(dth[:, 0])
    total_v = dvv[:, 0].copy()
    for j in range(1, m):
        total_v += rot.apply(dvv[:, j])
        rot = rot * Rotation.from_rotvec(dth[:, j])
    return rot.as_rotvec(), total_v


class SimSource:
    """A simulation as a message source for the pty emulators."""

    def __init__(self, sim):
        self.sim = sim
        self.duration_s = float(sim.scenario.duration_s)
        self._messages = gps_messages(sim.gnss, sim.scenario.gnss.leap_seconds)

    def gps_messages(self) -> Iterator[TimedMessage]:
        return iter(self._messages)

    def imu_samples(self, rate_hz: int, t0: float = 0.0) -> Iterator[TimedSample]:
        return imu_samples(self.sim, rate_hz, t0)


def imu_samples(sim, rate_hz: int, t0: float = 0.0) -> Iterator[TimedSample]:
    """A simulation's IMU samples from t0 at rate_hz (which must divide the simulated rate)."""
    base = sim.imu_rate_hz
    if base % rate_hz:
        raise ValueError(f"the simulation's IMU samples at {base} Hz: it cannot be served at {rate_hz} Hz "
                         f"(the rate must divide {base})")
    m = base // rate_hz
    dth, dv = sim.imu_dtheta, sim.imu_dv
    t = sim.imu_t[m - 1::m]
    if m > 1:
        dth, dv = combine_increments(dth, dv, m)
    for k in np.flatnonzero(t >= t0 - 1e-9):
        yield TimedSample(float(t[k]), bp3010.ImuSample(tuple(map(float, dth[k])), tuple(map(float, dv[k]))))
