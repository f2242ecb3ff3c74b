"""Decoded measurements of a logger session: the stage between records on disk
and time alignment.

GPS: measurement blocks (ID 23: time of week, stamp, pseudoranges), the
receiver's fixes (ID 21 time, week and ECEF position/velocity paired with the
ID 20 that carries HDOP, VDOP and the navigation mode), ephemeris subframes
(ID 22), Klobuchar coefficients (ID 75) and the GPS week (ID 21/49).
IMU: increments, status, counters and stamps; frames whose valid bit is clear
or that flag a range or test failure are left out and counted.

Nothing good is dropped silently: every skipped record is counted in
``skipped`` with the reason.
"""

from __future__ import annotations

from array import array
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from gpsins_logger import bp3010, superstar2 as ss2

from . import logs
from .filter import PseudorangeColumns

SECONDS_PER_WEEK = 604800.0
FIX_PAIR_TOLERANCE_S = 0.05  # an ID 20 and its ID 21 describe the same epoch (times to 1 ms)
GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ms")


@dataclass
class GpsMeasurements:
    week: int  # week of the first measurement block; times below count from its start
    tow: np.ndarray  # (n,) receiver time of each ID 23, s (continuing past the week end)
    stamps: np.ndarray  # (n,) system stamps
    pseudoranges: PseudorangeColumns  # [t, prn, pseudorange m, C/N0 dB-Hz, lock count]: GPS satellites of every block
    fixes: np.ndarray  # (m, 10) [t, r xyz, v xyz, hdop, vdop, mode], t in the same time base
    fix_sats: np.ndarray  # (m,) satellites used
    ephemerides: list[tuple[float, ss2.EphemerisWords]]  # (receive time, words)
    iono: ss2.IonoUtc | None
    leap_s: int | None

    def pseudorange_table(self) -> np.ndarray:
        """(k, 5) [t, prn, pseudorange m, C/N0 dB-Hz, lock count]: GPS satellites of every block."""
        return self.pseudoranges[:]

    def decoded_ephemerides(self, skipped: Counter | None = None) -> list:
        """The ID 22 subframes decoded (IS-GPS-200) by the core; inconsistent sets are counted and left out."""
        from . import _core

        out = []
        for _, w in self.ephemerides:
            try:
                out.append(_core.gnss.decode_subframes(w.subframes, w.prn, self.week))
            except ValueError:
                if skipped is not None:
                    skipped["gps: ephemerides with inconsistent IODE/IODC"] += 1
        return out


@dataclass
class Decoded:
    gps: GpsMeasurements
    imu: logs.ImuLog  # valid frames only
    skipped: Counter = field(default_factory=Counter)
    sidecar: dict = field(default_factory=dict)
    directory: Path | None = None


def _bad_imu(status: np.ndarray) -> np.ndarray:
    return ((status & bp3010.STATUS_VALID) == 0) | ((status & (bp3010.STATUS_GYRO_OVERRANGE | bp3010.STATUS_ACCEL_OVERRANGE
                                                                        | bp3010.STATUS_BIT_FAILURE)) != 0)


class _Observations:
    """The GPS observations of the measurement blocks as they are decoded: gathered as flat doubles
    (block index, prn, pseudorange, C/N0, lock count), moved every ``CHUNK`` rows into columns of the
    protocol's own exact types (C/N0 in quarter dB-Hz and the lock count are bytes, so float32 holds
    them exactly). A day's 8 million observations then take 25 bytes each, and no whole float table
    is ever built."""

    CHUNK = 1 << 16

    def __init__(self):
        self._rows = array("d")
        self._parts: list[list] = []

    def add(self, block: int, prn: int, pseudorange_m: float, cn0_dbhz: float, lock: int) -> None:
        self._rows.extend((block, prn, pseudorange_m, cn0_dbhz, lock))
        if len(self._rows) >= 5 * self.CHUNK:
            self._flush()

    def _flush(self) -> None:
        a = np.frombuffer(self._rows, dtype=np.float64).reshape(-1, 5)
        self._parts.append([a[:, 0].astype(np.uint32), a[:, 1].astype(np.uint8), a[:, 2].copy(),
                            a[:, 3].astype(np.float32), a[:, 4].astype(np.float32)])
        del a
        self._rows = array("d")

    def columns(self, block_times: np.ndarray) -> PseudorangeColumns:
        """The observations by columns, each block's index replaced by its time."""
        self._flush()
        parts, self._parts = self._parts, []
        cols = []
        for j in range(5):  # one column at a time, each part's piece dropped once copied
            cols.append(np.concatenate([p[j] for p in parts]))
            for p in parts:
                p[j] = None
        cols[0] = block_times[cols[0]]
        return PseudorangeColumns(*cols)


def decode_gps(files: logs.SensorFiles, skipped: Counter) -> GpsMeasurements:
    week = None
    tows, tstamps = array("d"), array("d")
    obs = _Observations()
    nav_user: list[tuple[float, ss2.NavUser]] = []
    nav_ecef: list[tuple[float, ss2.NavEcef]] = []
    ephs, iono, leap = [], None, None
    weeks = []  # (index in blocks when seen, week)
    for fr, st in files.iter_frames():
        try:
            msg_id, payload = ss2.decode_frame(fr)
            if msg_id == ss2.ID_MEASUREMENTS:
                m = ss2.Measurements.decode(payload)
                k = len(tows)
                for o in m.observations:
                    if not o.sbas:
                        obs.add(k, o.prn, m.pseudorange_m(o), o.cn0_dbhz, o.lock_count)
                tows.append(m.tow_s)
                tstamps.append(st)
            elif msg_id == ss2.ID_NAV_USER:
                nav_user.append((st, ss2.NavUser.decode(payload)))
            elif msg_id == ss2.ID_NAV_ECEF:
                e = ss2.NavEcef.decode(payload)
                nav_ecef.append((st, e))
                weeks.append((len(tows), e.week))
            elif msg_id == ss2.ID_RECEIVER_STATUS:
                weeks.append((len(tows), ss2.ReceiverStatus.decode(payload).week))
            elif msg_id == ss2.ID_EPHEMERIS:
                ephs.append((st, ss2.EphemerisWords.decode(payload)))
            elif msg_id == ss2.ID_IONO_UTC:
                iono = ss2.IonoUtc.decode(payload)
                leap = iono.leap_s
            elif msg_id == ss2.ID_LEAP:
                leap = ss2.LeapSeconds.decode(payload).leap_s
        except ss2.ProtocolError:
            skipped["gps frames that do not decode"] += 1
    if not tows:
        raise logs.LogError("no GPS measurement blocks (ID 23) in the session: GPS time is unknown")
    if not weeks:
        raise logs.LogError("no GPS week in the session (ID 21 or 49)")
    week = weeks[0][1]
    tow = np.frombuffer(tows, dtype=np.float64)
    # Time of week continues past a week rollover (tow drops by a week).
    tow = tow + SECONDS_PER_WEEK * np.concatenate([[0], np.cumsum(np.diff(tow) < -SECONDS_PER_WEEK / 2)])
    prs = obs.columns(tow)

    # Pair each ID 21 with the ID 20 of the same epoch, by GPS time (stamps can jump with the clock).
    fixes, sats = [], []
    ecef_t = np.array([(e.week - week) * SECONDS_PER_WEEK + e.tow_s for _, e in nav_ecef]).reshape(-1)
    user_t = _nav_user_times(nav_user, nav_ecef, ecef_t, leap, week, skipped)
    order = np.argsort(user_t, kind="stable")
    for (st, e), t in zip(nav_ecef, ecef_t):
        j = np.searchsorted(user_t[order], t)
        near = [order[i] for i in (j - 1, j) if 0 <= i < len(order)]
        k = min(near, key=lambda i: abs(user_t[i] - t)) if near else -1
        if k < 0 or not abs(user_t[k] - t) <= FIX_PAIR_TOLERANCE_S:
            skipped["ID 21 fixes without an ID 20 of the same epoch (no HDOP/VDOP/mode)"] += 1
            continue
        u = nav_user[k][1]
        mode = u.nav_mode if u.has_fix and np.any([e.x_m, e.y_m, e.z_m]) else 0
        mode = {4: 2, 5: 3}.get(mode, mode)
        fixes.append([t, e.x_m, e.y_m, e.z_m, e.vx_mps, e.vy_mps, e.vz_mps, max(u.hdop, 0.1), max(u.vdop, 0.1),
                      mode])
        sats.append(u.sats_used)
    return GpsMeasurements(week, tow, np.array(tstamps), prs, np.array(fixes).reshape(-1, 10),
                           np.array(sats, dtype=int), ephs, iono, leap)


def _utc_seconds(u: ss2.NavUser) -> float:
    """UTC of an ID 20 as seconds since the GPS epoch (no leap seconds); NaN if its date is not valid."""
    try:
        day = np.datetime64(f"{u.year:04d}-{u.month:02d}-{u.day:02d}", "ms")
    except ValueError:
        return float("nan")
    if not (0 <= u.hour < 24 and 0 <= u.minute < 60 and 0 <= u.second < 61):
        return float("nan")
    return float((day - GPS_EPOCH) / np.timedelta64(1, "s")) + 3600.0 * u.hour + 60.0 * u.minute + u.second


def _nav_user_times(nav_user: list, nav_ecef: list, ecef_t: np.ndarray, leap: int | None, week: int,
                    skipped: Counter) -> np.ndarray:
    """GPS time of each ID 20 in the fixes' time base. Without a leap-second count from the
    receiver (ID 75/113): the whole number of seconds that lines most ID 20s up with the ID 21
    nearest by stamp (the receiver sends the pair together; a clock step mispairs only a few)."""
    utc = np.array([_utc_seconds(u) for _, u in nav_user]).reshape(-1) - week * SECONDS_PER_WEEK
    if np.isnan(utc).any():
        skipped["ID 20 with an invalid date (not paired)"] += int(np.isnan(utc).sum())
    if leap is None and len(utc) and len(ecef_t):
        ustamps = np.array([st for st, _ in nav_user])
        k = np.clip(np.searchsorted(ustamps, [st for st, _ in nav_ecef]), 0, len(ustamps) - 1)
        diff = np.round(ecef_t - utc[k])
        vals, counts = np.unique(diff[np.isfinite(diff)], return_counts=True)
        leap = int(vals[np.argmax(counts)]) if len(vals) else 0
    return utc + (leap or 0)


def read_counting_damage(directory: str | Path, imu_frames: bool = True) -> tuple[logs.SessionLog, Counter]:
    """A session's record files, and what the readers skipped in them, by reason
    (imu_frames: see :func:`logs.read_session`)."""
    session = logs.read_session(directory, imu_frames)
    skipped: Counter = Counter()
    for name, sensor in session.sensors.items():
        st = sensor.stats()
        if st["discarded_bytes"]:
            skipped[f"{name}: bytes between frames (garbage or damaged frames)"] += st["discarded_bytes"]
        if st.get("bad_stamps"):
            skipped[f"{name}: records with impossible stamps (their bytes are counted above)"] += st["bad_stamps"]
        if st["truncated_tail_bytes"]:
            skipped[f"{name}: truncated last record, bytes"] += st["truncated_tail_bytes"]
    return session, skipped


def decode_session(directory: str | Path) -> Decoded:
    """The session decoded for replay; its IMU is decoded as it is read (no frames kept)."""
    session, skipped = read_counting_damage(directory, imu_frames=False)
    if "gps" not in session.sensors or not session.sensors["gps"].count:
        raise logs.LogError(f"{directory}: no GPS records")
    if "imu" not in session.sensors or not session.sensors["imu"].count:
        raise logs.LogError(f"{directory}: no IMU records")
    gps = decode_gps(session.sensors["gps"], skipped)
    return Decoded(gps, valid_imu(session, skipped), skipped, session.sidecar, Path(directory))


def valid_imu(session: logs.SessionLog, skipped: Counter) -> logs.ImuLog:
    """The session's IMU samples without the frames flagged invalid, over range or failing
    their test (counted). The session lets go of its IMU, so no second copy is held."""
    imu = session.imu()
    del session.sensors["imu"]
    bad = _bad_imu(imu.status)
    if bad.any():
        skipped["imu: frames flagged invalid, over range or test failure"] += int(bad.sum())
        imu.keep(~bad)
    return imu
